"""dynamixel_driver with use_sim_time on a test-published /clock (issue 11): the command watchdog
runs on simulated time. The real driver process, on each executor the runner offers (rclpy's events
executor, the default, and its Python executor: ``HSA_EXECUTOR``), and dynamixel_sdk on the emulated
MX-28 bus; the test owns /clock and steps it one 10 ms instant at a time, waiting for the driver's
read of that instant (``motor_states`` stamped with it) before it looks at the bus, so nothing
depends on how fast the loaded machine runs the driver.
"""

from __future__ import annotations

import threading
import time

import pytest
from builtin_interfaces.msg import Time
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from hsa_common import qos
from hsa_msgs.msg import PlanarActuation
from hsa_sim_node.mx28_emulator import MX28Emulator
from tests.ros.driver_fixtures import drivers
from tests.ros.driver_harness import (
    DriverProcess,
    command,
    goal_writes,
    make_emulator,
    torque,
    wait_until,
)
from tests.ros.faults import BEST_EFFORT, fault

pytestmark = pytest.mark.ros
__all__ = ["drivers"]  # fixture used by the tests below

TIMEOUT_S = 0.1  # command_timeout (the driver's default)
STEP_NS = 10_000_000  # one 10 ms instant = one cycle at the default 100 Hz
START_NS = 100_000_000_000  # simulated time starts at 100 s


class SimClock:
    """Publishes the simulated time ``ns`` on /clock every 10 ms of wall time (re-publishing keeps
    it still)."""

    def __init__(self, node) -> None:
        self.ns = START_NS  # held: the test moves it
        self._pub = node.create_publisher(Clock, "/clock", 10)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(0.01):
            self._pub.publish(Clock(clock=Time(sec=self.ns // 10**9, nanosec=self.ns % 10**9)))

    def subscribers(self) -> int:
        """Number of matched /clock subscriptions (the driver's time source)."""
        return self._pub.get_subscription_count()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


class StateStamps:
    """Header stamps [ns] of the driver's motor_states: the instants whose read cycle has run."""

    def __init__(self, node) -> None:
        self.stamps: list[int] = []
        node.create_subscription(JointState, "motor_states", self._on_state, BEST_EFFORT)

    def _on_state(self, msg: JointState) -> None:
        self.stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)

    def wait_cycle(self, ns: int, timeout: float = 20.0) -> bool:
        """Whether the driver read the bus at simulated time ``ns`` (within ``timeout`` s of wall
        time)."""
        return wait_until(lambda: ns in self.stamps, timeout=timeout)


@pytest.mark.parametrize("executor", ["events", "single"])
def test_watchdog_runs_on_simulated_time(tmp_path, drivers, ros_node, executor: str) -> None:
    clock = SimClock(ros_node)
    emulator: MX28Emulator | None = None
    try:
        states = StateStamps(ros_node)
        # The driver starts before its bus exists, with simulated time standing still (a lockstep
        # simulator waits for its participants before it moves /clock): the reconnect timer runs on
        # the wall clock, so it connects.
        drivers.append(
            driver := DriverProcess(
                str(tmp_path / "ttyDXL"),
                ("use_sim_time:=true", "watchdog_action:=relax", f"command_timeout:={TIMEOUT_S}"),
                env={"HSA_EXECUTOR": executor},
            ).wait_ready()
        )
        assert wait_until(lambda: bool(driver.log("bus not ready")), timeout=30.0), driver.output()
        assert wait_until(lambda: clock.subscribers() >= 1, timeout=30.0), (
            "the driver does not subscribe to /clock"
        )
        # the bus appears well after the driver got simulated time (reconnect_period is 0.2 s)
        time.sleep(1.0)
        emulator = make_emulator(tmp_path)
        assert wait_until(lambda: torque(emulator) == {True}, timeout=30.0), driver.output()
        assert clock.ns == START_NS
        pub = ros_node.create_publisher(PlanarActuation, "phi_cmd", qos.COMMAND)
        assert wait_until(lambda: pub.get_subscription_count() >= 1, timeout=10.0)

        # Simulated time stands still at T: a phi_cmd arrives at T, then 2 s of wall time pass
        # without /clock moving.
        held = clock.ns = START_NS + STEP_NS
        assert states.wait_cycle(held), (
            f"no read cycle at the held instant {held}\n{driver.output()}"
        )
        began = time.monotonic()
        pub.publish(command(0.3, 0.3))
        assert wait_until(lambda: goal_writes(emulator, began), timeout=10.0), (
            "the command was not written"
        )
        time.sleep(2.0)
        assert torque(emulator) == {True} and not driver.log("no phi_cmd"), (
            "watchdog fired while time stood still"
        )

        # Step the clock 10 ms at a time: the watchdog fires at the first cycle whose command age
        # exceeds the timeout in simulated time (T + 0.10 s or T + 0.11 s, by float rounding), not a
        # cycle earlier.
        fired = None
        for k in range(1, 21):
            clock.ns = held + k * STEP_NS
            assert states.wait_cycle(clock.ns), (
                f"no read cycle at T + {k * 10} ms\n{driver.output()}"
            )
            if torque(emulator) == {False}:
                fired = k * STEP_NS * 1e-9
                break
        assert fired is not None, (
            f"watchdog never fired within 0.2 s of simulated time\n{driver.output()}"
        )
        assert TIMEOUT_S - 1e-6 <= fired <= TIMEOUT_S + STEP_NS * 1e-9 + 1e-6, (
            f"fired {fired:.3f} s after T"
        )
        # the age the driver logs is on its own clock: simulated time, so exactly the expiry
        (line,) = driver.log("(> 0.1 s): relaxing")
        age = float(line.split("no phi_cmd for ")[1].split(" s")[0])
        assert abs(age - fired) < 1e-6, (age, fired)
        wall = time.monotonic() - began
        fault(
            "phi_cmd stops with use_sim_time (/clock held 2 s, then stepped 10 ms)",
            f"watchdog relaxed the motors {fired:.2f} s of simulated time after the last command "
            f"({wall:.1f} s of wall time), never while /clock stood still",
            "next phi_cmd",
        )
    finally:
        clock.close()
        if emulator is not None:
            emulator.stop()

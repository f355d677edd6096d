"""Shared pieces of the fault-injection tests (issue 6): node start-up with a captured log, a
pausable 200 Hz mocap stream with sample injection, /diagnostics collection, and the one-line
``FAULT`` summaries for the closing report."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.time import Time

from hsa_common import qos
from hsa_common.launcher import find_executable
from hsa_core.sensing import mocap
from hsa_msgs.msg import Setpoint
from tests.ros.conftest import CollectedProcess, start_process
from tests.ros.test_mocap_bridge import pose_msg, wait_until

__all__ = [
    "BEST_EFFORT",
    "EXECUTABLES",
    "OFFSET_CHIEE",
    "SETPOINT_CHIEE",
    "DiagnosticsLog",
    "MocapStream",
    "NodeProcess",
    "Recorder",
    "fault",
    "sec",
    "setpoint",
    "start_all",
    "wait_until",
]

EXECUTABLES = {
    "mocap_bridge": "hsa_mocap_bridge",
    "kinematics_node": "hsa_kinematics_node",
    "controller_node": "hsa_controller_node",
    "planner_node": "hsa_planner_node",
    "setpoint_sequencer": "hsa_planner_node",
}
SETPOINT_CHIEE = np.array([0.00479247, 0.12781018, -0.066980133])
"""χ_ee^d of the FPU worked example (planning_and_control.md §2.2) that ``setpoint()`` returns."""
OFFSET_CHIEE = SETPOINT_CHIEE + np.array([0.002, 0.001, 0.0])
"""A pose 2.2 mm from the setpoint: the controller's integrator state grows steadily while it tracks
it."""


BEST_EFFORT = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
"""Subscription profile for the SENSOR streams (a reliable subscription does not match a best-effort
publisher)."""


class Recorder:
    """Raw subscription, decoded only when read (keeps the observing test process fast enough for
    200 Hz)."""

    def __init__(
        self, node: Node, msg_type: type, topic: str, profile: QoSProfile | int = 500
    ) -> None:
        self.msg_type = msg_type
        self.raw: list[bytes] = []
        node.create_subscription(msg_type, topic, self.raw.append, profile, raw=True)

    def __len__(self) -> int:
        return len(self.raw)

    def since(self, start: int = 0) -> list:
        """Messages from index ``start`` on, decoded."""
        return [deserialize_message(b, self.msg_type) for b in self.raw[start:]]


def setpoint() -> Setpoint:
    """The FPU worked example of planning_and_control.md §2.2 (exact model) as a Setpoint
    message."""
    msg = Setpoint(phi_ss=np.array([1.9846028, 1.6323408]), optimality_error=1e-16)
    msg.header.frame_id = "hsa_base"
    msg.chiee_des.x, msg.chiee_des.y, msg.chiee_des.theta = 0.00479247, 0.12781018, -0.066980133
    msg.q_des.kappa_be, msg.q_des.sigma_sh, msg.q_des.sigma_ax = (
        -1.1352565,
        0.0080816386,
        0.30410104,
    )
    return msg


def sec(stamp: object) -> float:
    """builtin_interfaces/Time → float seconds."""
    return stamp.sec + stamp.nanosec * 1e-9  # type: ignore[attr-defined]


def fault(name: str, behaviour: str, recovery: float | str) -> str:
    """Print (and return) the one-line summary of one injected fault for the closing report."""
    figure = f"{recovery:.3f} s" if isinstance(recovery, float) else recovery
    line = f"FAULT {name}: {behaviour}, recovery {figure}"
    print(line, flush=True)
    return line


class NodeProcess(CollectedProcess):
    """One node process (console script, ``--ros-args`` list) whose output is collected by a reader
    thread."""

    def __init__(self, executable: str, ros_args: Sequence[str]) -> None:
        super().__init__(
            start_process(
                [find_executable(EXECUTABLES[executable], executable), "--ros-args", *ros_args]
            )
        )


def start_all(specs: dict[str, tuple[str, Sequence[str]]]) -> dict[str, NodeProcess]:
    """Start several nodes at once (they compile in parallel) and wait until all are ready."""
    procs = {key: NodeProcess(exe, args) for key, (exe, args) in specs.items()}
    for proc in procs.values():
        proc.wait_ready()
    return procs


class MocapStream:
    """Publishes the platform pose of a planar pose at 200 Hz (node-clock stamps) from a thread;
    ``paused`` stops it; ``inject`` queues extra messages that go out right after the next regular
    sample."""

    def __init__(self, node: Node, topic: str, chiee: Sequence[float], rate: float = 200.0) -> None:
        self.node = node
        self.pub = node.create_publisher(PoseStamped, topic, qos.SENSOR)
        self.world = mocap.planar_to_world(chiee, (0.0, 0.0, 0.0))
        self.period = 1.0 / rate
        self.sent: list[int] = []  # stamps [ns] of the regular samples
        self.paused = threading.Event()
        self._extra: list[Callable[[int], PoseStamped]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            next_t += self.period
            with (
                self._lock
            ):  # pause() cannot interleave: no sample leaves after it read the last stamp
                if not self.paused.is_set():
                    stamp = self.node.get_clock().now().nanoseconds
                    self.pub.publish(pose_msg(stamp, *self.world))
                    self.sent.append(stamp)
                    extra, self._extra = self._extra, []
                    for make in extra:
                        self.pub.publish(make(stamp))
            time.sleep(max(0.0, next_t - time.monotonic()))

    def inject(self, make: Callable[[int], PoseStamped]) -> None:
        """Queue one extra message built from the stamp [ns] of the regular sample it follows."""
        with self._lock:
            self._extra.append(make)

    def pause(self, duration: float) -> tuple[int, int]:
        """Stop the stream for ``duration`` seconds; return the stamps [ns] of the last sample
        before and the first after the outage."""
        with self._lock:
            self.paused.set()
            last = self.sent[-1]
        time.sleep(duration)
        n = len(self.sent)
        self.paused.clear()
        assert wait_until(lambda: len(self.sent) > n, 2.0), "the stream did not resume"
        return last, self.sent[n]

    def close(self) -> None:
        """Stop the thread."""
        self._stop.set()
        self._thread.join(timeout=2.0)


class DiagnosticsLog:
    """Every /diagnostics array received, searchable by status name."""

    def __init__(self, node: Node) -> None:
        self.arrays: list[DiagnosticArray] = []
        self.first_seen: dict[
            str, float
        ] = {}  # status name -> time.monotonic() of its first report
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_array, 100)

    def _on_array(self, msg: DiagnosticArray) -> None:
        now = time.monotonic()
        for status in msg.status:
            self.first_seen.setdefault(status.name, now)
        self.arrays.append(msg)

    def statuses(
        self, name: str, after_ns: int = 0
    ) -> list[tuple[DiagnosticStatus, dict[str, str]]]:
        """Statuses called ``name`` from arrays stamped after ``after_ns``, with their values."""
        return [
            (s, {kv.key: kv.value for kv in s.values})
            for a in list(self.arrays)
            for s in a.status
            if s.name == name and Time.from_msg(a.header.stamp).nanoseconds > after_ns
        ]

    def wait(
        self,
        name: str,
        accept: Callable[[DiagnosticStatus, dict[str, str]], bool] = lambda s, v: True,
        after_ns: int = 0,
        timeout: float = 10.0,
    ) -> tuple[DiagnosticStatus, dict[str, str]]:
        """The first status called ``name`` (after ``after_ns``) that ``accept`` takes; fails after
        ``timeout``."""
        found: list[tuple[DiagnosticStatus, dict[str, str]]] = []

        def match() -> bool:
            found[:] = [(s, v) for s, v in self.statuses(name, after_ns) if accept(s, v)]
            return bool(found)

        assert wait_until(match, timeout), (
            f"no matching {name!r} status; last: {self.statuses(name)[-1:]}"
        )
        return found[0]

    def names(self) -> set[str]:
        """Every status name seen so far."""
        return {s.name for a in list(self.arrays) for s in a.status}

"""The runner's lockstep spin (``hsa_common.runner.spin_lockstep``) on both executors it runs
(``HSA_EXECUTOR``: rclpy's events executor, the default, and its Python executor), in the test
process: a participant reports once it has run the last callback of a burst, with every message
counted; a timer on simulated time runs when /clock moves and its next due time reaches the report,
as does a new timer's; a callback's exception ends the spin."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Int32

from hsa_common import lockstep, runner
from hsa_common.convert import stamp_msg
from hsa_msgs.msg import LockstepAck
from tests.ros.conftest import wait_until

pytestmark = pytest.mark.ros

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
NAME = "/spin_probe"


@dataclass
class Spin:
    """A participant node spun by the runner's lockstep spin in a thread of the test process (the
    default context), and a second context's node that drives it and hears its reports."""

    node: Node
    peer: Node
    reports: list[LockstepAck] = field(default_factory=list)
    error: list[BaseException] = field(default_factory=list)
    thread: threading.Thread | None = None

    def start(self) -> None:
        """Spin the participant as :func:`hsa_common.runner.run_nodes` does in lockstep."""
        executor = runner.make_executor(lockstep_spin=True)
        executor.add_node(self.node)
        participant = lockstep.Group([lockstep.Participant(self.node)])
        self.stop: list[int] = []

        def spin() -> None:
            try:
                runner.spin_lockstep(executor, participant, self.stop)
            except BaseException as exc:  # the test asserts on it
                self.error.append(exc)

        self.executor = executor
        self.thread = threading.Thread(target=spin, daemon=True)
        self.thread.start()

    def taken(self, topic: str) -> list[int]:
        """The participant's count of ``topic`` in each of its reports so far."""
        return [dict(zip(r.sub_topics, r.taken)).get(topic, 0) for r in list(self.reports)]


@pytest.fixture(params=["events", "single"])
def spin(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable]:
    """``make(setup, sim_time)``: a :class:`Spin` whose participant node is created here
    (``use_sim_time`` as given) and given its entities by ``setup(node)``, under each executor."""
    monkeypatch.setenv("HSA_EXECUTOR", request.param)
    rclpy.init()
    peer_context = Context()
    rclpy.init(context=peer_context)
    peer = rclpy.create_node("spin_peer", context=peer_context)
    peer_executor = SingleThreadedExecutor(context=peer_context)
    peer_executor.add_node(peer)
    peer_thread = threading.Thread(target=peer_executor.spin, daemon=True)
    peer_thread.start()
    made: list[Spin] = []

    def make(setup: Callable[[Node], None], sim_time: bool = False) -> Spin:
        node = rclpy.create_node(
            NAME.lstrip("/"), parameter_overrides=[Parameter("use_sim_time", value=sim_time)]
        )
        setup(node)
        s = Spin(node, peer)
        peer.create_subscription(
            LockstepAck,
            lockstep.ACK_TOPIC,
            lambda m: s.reports.append(m) if m.node == NAME else None,
            lockstep.ACK_READER_QOS,
        )
        s.start()
        made.append(s)
        return s

    try:
        yield make
    finally:
        for s in made:
            s.stop.append(1)
            if s.thread is not None:
                s.thread.join(timeout=5)
            s.executor.shutdown()
            s.node.destroy_node()
        peer_executor.shutdown()
        peer_thread.join(timeout=5)
        peer.destroy_node()
        rclpy.try_shutdown(context=peer_context)
        rclpy.try_shutdown()


def test_a_participant_reports_after_the_last_message_of_a_burst(spin: Callable) -> None:
    got: list[int] = []
    s = spin(
        lambda n: n.create_subscription(
            Int32, "/probe/burst", lambda m: got.append(m.data), RELIABLE
        )
    )
    pub = s.peer.create_publisher(Int32, "/probe/burst", RELIABLE)
    assert wait_until(lambda: pub.get_subscription_count() >= 1, timeout=30.0)
    assert wait_until(lambda: bool(s.reports), timeout=30.0), "no report before the burst"
    for k in range(50):
        pub.publish(Int32(data=k))
    assert wait_until(lambda: 50 in s.taken("/probe/burst"), timeout=30.0), s.taken("/probe/burst")
    assert got == list(range(50))
    counts = s.taken("/probe/burst")
    assert counts == sorted(counts), f"a report went back: {counts}"
    assert not s.error, s.error


def test_a_timer_on_simulated_time_runs_when_the_clock_moves(spin: Callable) -> None:
    ticks: list[int] = []

    def setup(node: Node) -> None:
        node.create_timer(0.1, lambda: ticks.append(node.get_clock().now().nanoseconds))

    s = spin(setup, sim_time=True)
    clock = s.peer.create_publisher(Clock, "/clock", RELIABLE)
    assert wait_until(lambda: clock.get_subscription_count() >= 1, timeout=30.0)
    assert wait_until(lambda: any(r.next_due == 100_000_000 for r in s.reports), timeout=30.0), [
        r.next_due for r in s.reports
    ]
    for t_ns, due in ((100_000_000, 200_000_000), (250_000_000, 300_000_000)):
        # sent again until seen, as the simulator does: rclpy's time source takes /clock best effort
        assert wait_until(
            lambda d=due: s.reports[-1].next_due == d,
            timeout=30.0,
            step=lambda t=t_ns: clock.publish(Clock(clock=stamp_msg(t))),
            poll=0.05,
        ), (t_ns, [r.next_due for r in s.reports])
    assert ticks == [100_000_000, 250_000_000]
    # a timer made while nothing runs (here by the test's thread) still reaches the next report
    s.node.create_timer(0.01, lambda: None)
    assert wait_until(lambda: s.reports[-1].next_due == 260_000_000, timeout=30.0), [
        r.next_due for r in s.reports
    ]
    assert not s.error, s.error


def test_a_callback_exception_ends_the_spin(spin: Callable) -> None:
    def fails(msg: Int32) -> None:
        raise ValueError(f"bad {msg.data}")

    s = spin(lambda n: n.create_subscription(Int32, "/probe/fail", fails, RELIABLE))
    pub = s.peer.create_publisher(Int32, "/probe/fail", RELIABLE)
    assert wait_until(lambda: pub.get_subscription_count() >= 1, timeout=30.0)
    pub.publish(Int32(data=7))
    assert wait_until(lambda: bool(s.error), timeout=30.0)
    assert [str(e) for e in s.error] == ["bad 7"]
    assert s.thread is not None
    s.thread.join(timeout=5)
    assert not s.thread.is_alive()

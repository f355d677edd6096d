"""hsa_common.lockstep.LockstepExecutor, the executor of the runner's lockstep spin, in the test
process: every message is taken once and in order, entities created or destroyed between waits are
followed, a callback's exception reaches the spin, and a pending task still runs; the same with
rclpy's own wait, which runs where rclpy lacks the internals the lean wait uses."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
import rclpy
from rclpy.executors import TimeoutException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Int32

from hsa_common.lockstep import LockstepExecutor

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture
def node() -> Iterator[Node]:
    """A node in the test process (its own context)."""
    rclpy.init()
    node = rclpy.create_node("lockstep_executor_probe")
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def spin_until(
    executor: LockstepExecutor, done: Callable[[], object], errors: list[Exception] | None = None
) -> list[Exception]:
    """Run ready callbacks as the lockstep spin does until ``done()``; the callbacks' errors (into
    ``errors`` if given)."""
    errors = [] if errors is None else errors
    for _ in range(2000):
        if done():
            return errors
        try:
            handler, _, _ = executor.wait_for_ready_callbacks(timeout_sec=0.005)
        except TimeoutException:
            continue
        handler()
        if handler.exception() is not None:
            errors.append(handler.exception())
    raise AssertionError("not done")


def matched(executor: LockstepExecutor, pub: object, subscriptions: int) -> None:
    """Spin until ``pub`` has matched ``subscriptions`` subscriptions."""
    spin_until(executor, lambda: pub.get_subscription_count() >= subscriptions)


@pytest.mark.parametrize("lean", [True, False], ids=["lean", "rclpy_wait"])
def test_the_lockstep_executor_takes_every_message_once_and_follows_new_entities(
    node: Node, lean: bool
) -> None:
    executor = LockstepExecutor()
    assert executor.lean  # this rclpy has every internal the lean wait builds on
    executor.lean = lean  # False: what an rclpy without them runs
    executor.add_node(node)
    got: list[int] = []
    pub = node.create_publisher(Int32, "/probe/a", RELIABLE)
    sub = node.create_subscription(Int32, "/probe/a", lambda m: got.append(m.data), RELIABLE)
    matched(executor, pub, 1)
    for k in range(50):
        pub.publish(Int32(data=k))
    spin_until(executor, lambda: len(got) >= 50)
    assert got == list(range(50))

    late: list[int] = []  # created after the wait set was built
    node.create_subscription(Int32, "/probe/a", lambda m: late.append(m.data), RELIABLE)
    matched(executor, pub, 2)
    node.destroy_subscription(sub)  # destroyed between waits: no longer served
    matched(executor, pub, 1)
    pub.publish(Int32(data=50))
    spin_until(executor, lambda: late == [50])
    assert got == list(range(50))

    def fails(msg: Int32) -> None:
        raise ValueError(f"bad {msg.data}")

    node.create_subscription(Int32, "/probe/b", fails, RELIABLE)
    failing = node.create_publisher(Int32, "/probe/b", RELIABLE)
    matched(executor, failing, 1)
    failing.publish(Int32(data=7))
    errors: list[Exception] = []
    spin_until(executor, lambda: bool(errors), errors)
    assert [str(e) for e in errors] == ["bad 7"]

    ran: list[str] = []

    async def coroutine() -> None:
        ran.append("task")

    executor.create_task(coroutine)  # a pending task: rclpy's own path runs it
    spin_until(executor, lambda: ran == ["task"])
    executor.shutdown()

"""Malformed CDR on the graph (issue 22, item 5): a controller_node and a bag_recorder as real
processes, fed raw buffers that do not deserialize on two topics of different types, between valid
messages.

The recorder keeps only what decodes and counts the rest per topic (its /diagnostics, its final
line, the bag's custom_data); the controller prints no rcutils "error state is being overwritten"
block, at most one throttled line.
"""

from __future__ import annotations

import struct
import time
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rclpy.serialization import serialize_message

from hsa_bag.bagio import Bag
from hsa_bag.recorder import UNDECODABLE_KEY
from hsa_bag.storage import read_metadata
from hsa_common.launcher import find_executable
from hsa_msgs.msg import PlanarState, Setpoint
from tests.ros.conftest import CollectedProcess, start_process, wait_until
from tests.ros.faults import DiagnosticsLog, NodeProcess

pytestmark = pytest.mark.ros

NS = "/malformed"
STATE, SETPOINT = f"{NS}/state", f"{NS}/setpoint"
N_BAD, N_GOOD = 20, 10  # per topic
# the recorder then takes every message (the controller's best-effort reader too)
RELIABLE = QoSProfile(depth=100)
# the controller's setpoint reader
LATCHED = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def malformed(good: bytes, k: int) -> bytes:
    """The k-th of four raw buffers that fail to deserialize: truncated, garbage, encapsulation
    only, a string length beyond the buffer (header.frame_id)."""
    return [
        good[: len(good) // 2],
        b"\x00\x01\x00\x00" + b"\xff" * 40,
        b"\x00\x01\x00\x00",
        good[:12] + struct.pack("<I", 0x7FFFFFFF) + good[16:],
    ][k % 4]


def test_malformed_messages_are_left_out_of_the_bag_and_print_no_error_blocks(
    ros_node: Node, tmp_path: Path
) -> None:
    bag = tmp_path / "bag"
    recorder = CollectedProcess(
        start_process(
            [
                find_executable("hsa_bag", "bag_recorder"),
                "--ros-args",
                "-p",
                f"output:={bag}",
                "-p",
                f"topics:=[{STATE}, {SETPOINT}]",
            ]
        )
    )
    controller = NodeProcess("controller_node", ["-r", f"__ns:={NS}", "-p", "driver_timeout:=0.0"])
    diagnostics = DiagnosticsLog(ros_node)
    pubs = {
        STATE: ros_node.create_publisher(PlanarState, STATE, RELIABLE),
        SETPOINT: ros_node.create_publisher(Setpoint, SETPOINT, LATCHED),
    }
    good = {STATE: serialize_message(PlanarState()), SETPOINT: serialize_message(Setpoint())}
    try:
        recorder.wait_ready()
        controller.wait_ready()
        assert wait_until(lambda: all(p.get_subscription_count() == 2 for p in pubs.values()), 30.0)
        # the recorder subscribes on discovery: give both subscriptions time to match back
        time.sleep(1.0)
        for k in range(N_BAD):
            for (
                topic,
                pub,
            ) in pubs.items():  # alternating types: each malformed take sets a different error text
                pub.publish(malformed(good[topic], k))
                if k % 2 == 0:
                    pub.publish(good[topic])
            time.sleep(0.02)
        status, values = diagnostics.wait(
            "bag_recorder: recording",
            lambda s, v: (
                v.get(f"undecodable {STATE}") == str(N_BAD)
                and v.get(f"undecodable {SETPOINT}") == str(N_BAD)
            ),
            timeout=15.0,
        )
        assert status.level == DiagnosticStatus.WARN and "undecodable" in status.message, (
            status.message
        )
    finally:
        assert controller.stop() == 0
        assert recorder.stop() == 0

    printed = controller.output()
    assert "rcutils_set_error_state" not in printed and "being overwritten" not in printed, printed
    assert 1 <= len(controller.log("middleware error")) <= 2, printed  # throttled: one line per 5 s
    # taken raw: refused and counted, no crash
    assert controller.log("rejected an undecodable setpoint"), printed
    summary = recorder.log("wrote ")
    assert (
        summary
        and f"left out undecodable messages: {SETPOINT}: {N_BAD}, {STATE}: {N_BAD}" in summary[0]
    )
    with Bag(bag) as reader:
        assert {t: reader.topics[t].count for t in (STATE, SETPOINT)} == {
            STATE: N_GOOD,
            SETPOINT: N_GOOD,
        }
        assert (
            sum(1 for t in (STATE, SETPOINT) for _ in reader.decoded(t)) == 2 * N_GOOD
            and not reader.skipped
        )
    assert (
        read_metadata(bag)["custom_data"][UNDECODABLE_KEY]
        == f"{SETPOINT}: {N_BAD}, {STATE}: {N_BAD}"
    )

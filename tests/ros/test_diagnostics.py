"""/diagnostics from every node of the sim graph (issue 6): launch_scripts/sim.launch.yaml runs as
in ./run.sh, and each node's status must appear on /diagnostics within a few seconds of the node
logging ``ready``, carrying the rates, stale-input and rejection counters and failure counts it
documents; once the sequencer's first setpoint is active the pipeline reports healthy input rates
and the controller reports tracking."""

from __future__ import annotations

import re
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.ros.conftest import start_process, stop_process
from tests.ros.faults import DiagnosticsLog, fault, wait_until

pytestmark = [pytest.mark.ros, pytest.mark.slow]

GRAPH = Path(__file__).parents[2] / "launch_scripts" / "sim.launch.yaml"
READY = re.compile(r"\[hsa\.(\w+)\]: ready")
# [s] a status must follow `ready` within this: 1 Hz reports, with room for a loaded 2-core machine
# (4 s was exceeded once, 5.1 s, beside two busy processes with a cold JAX cache)
DIAGNOSTICS_DELAY = 10.0
# node -> (a status name it publishes, values that status must carry)
EXPECTED = {
    "sim_node": ("sim_node: world", ()),
    "dynamixel_driver": ("dynamixel_driver: bus", ()),
    "mocap_bridge": (
        "mocap_bridge: platform",
        (
            "received",
            "published",
            "rejected_non_finite",
            "rejected_jump",
            "rejected_workspace",
            "rejected_out_of_order",
            "input_rate_hz",
            "output_rate_hz",
        ),
    ),
    "kinematics_node": (
        "kinematics_node: estimator",
        ("received", "published", "rejected", "window_restarts", "input_rate_hz", "output_rate_hz"),
    ),
    "planner_node": ("planner_node: planning", ("requests", "failures", "last failure")),
    "controller_node": (
        "controller_node: control loop",
        (
            "mode",
            "estop",
            "tick rate [Hz]",
            "stale_events",
            "stale_stops",
            "rejected_states",
            "rejected_setpoints",
            "time_since_last_state [s]",
        ),
    ),
    "setpoint_sequencer": ("setpoint_sequencer: sequence", ("state", "failures", "published")),
    "bag_recorder": ("bag_recorder: recording", ()),
}


class Graph:
    """The launcher process with its output read by a thread: ready times per node."""

    def __init__(self, bag: Path) -> None:
        # 1 Hz of real time is what this test asserts
        self.proc = start_process(
            [
                sys.executable,
                "-m",
                "hsa_common.launcher",
                str(GRAPH),
                f"bag_dir:={bag}",
                "clock:=wall",
            ]
        )
        self.ready: dict[str, float] = {}  # node -> time.monotonic() when its `ready` line was read
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line)
            match = READY.search(line)
            if match:
                self.ready.setdefault(match.group(1), time.monotonic())


@pytest.fixture
def graph(tmp_path) -> Iterator[Graph]:
    """The sim graph, stopped (SIGINT to its process group) at teardown."""
    graph = Graph(tmp_path / "bag")
    yield graph
    code = stop_process(graph.proc, timeout=15.0)
    print(f"sim graph stopped with exit code {code}")


def test_every_node_reports_on_diagnostics(graph, ros_node) -> None:
    diagnostics = DiagnosticsLog(ros_node)
    started = time.monotonic()
    assert wait_until(lambda: set(EXPECTED) <= graph.ready.keys(), 240.0), (
        f"not ready: {set(EXPECTED) - graph.ready.keys()}\n{''.join(graph.lines[-40:])}"
    )
    last_ready = max(graph.ready.values())
    assert wait_until(
        lambda: all(EXPECTED[n][0] in diagnostics.first_seen for n in EXPECTED),
        DIAGNOSTICS_DELAY + 2,
    ), (
        "missing on /diagnostics: "
        f"{[EXPECTED[n][0] for n in EXPECTED if EXPECTED[n][0] not in diagnostics.first_seen]}"
    )
    delays = {
        node: diagnostics.first_seen[status] - graph.ready[node]
        for node, (status, _) in EXPECTED.items()
    }
    slow = {node: round(d, 2) for node, d in delays.items() if d > DIAGNOSTICS_DELAY}
    assert not slow, f"status later than {DIAGNOSTICS_DELAY} s after `ready`: {slow}"
    for node, (status, keys) in EXPECTED.items():
        values = diagnostics.statuses(status)[-1][1]
        assert set(keys) <= values.keys(), (node, sorted(set(keys) - values.keys()))

    # the sequencer's first setpoint arrives (t = 0 of the schedule): the controller tracks and says
    # so, the pipeline inputs are healthy
    after = ros_node.get_clock().now().nanoseconds
    _, controller = diagnostics.wait(
        "controller_node: control loop",
        lambda s, v: v["mode"] == "tracking",
        after_ns=after,
        timeout=60.0,
    )
    tracking_after = time.monotonic() - last_ready
    _, values = diagnostics.wait(
        "mocap_bridge: platform", after_ns=ros_node.get_clock().now().nanoseconds
    )
    assert float(values["input_rate_hz"]) > 100.0 and int(values["rejected_non_finite"]) == 0, (
        values
    )
    assert controller["estop"] == "False" and float(controller["tick rate [Hz]"]) > 20.0, controller
    diagnostics.wait("setpoint_sequencer: sequence", lambda s, v: int(v["published"]) >= 1)
    # a few seconds of closed-loop running: how often did the loaded graph starve the controller?
    time.sleep(3.0)
    controller = diagnostics.statuses("controller_node: control loop")[-1][1]
    nodes = sorted({name.split(":")[0] for name in diagnostics.names()})
    fault(
        "none (diagnostics of the sim graph)",
        f"{len(nodes)} nodes on /diagnostics ({', '.join(nodes)}), each within "
        f"{max(delays.values()):.2f} s of `ready`; all ready {last_ready - started:.1f} s after "
        f"launch, controller reports tracking {tracking_after:.1f} s later; after "
        f"{controller['ticks']} ticks: stale_events {controller['stale_events']}, held_ticks "
        f"{controller['held_ticks']}, stale_stops {controller['stale_stops']}, rejected_states "
        f"{controller['rejected_states']}",
        "n/a",
    )

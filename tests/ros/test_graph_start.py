"""Graph start-up with real processes: each node of a graph starts on the command line its graph
gives it (the parameter files of that graph, integer spellings of numeric launch arguments), and a
node that refuses to start stops the whole graph at once with its message and its exit code (fail
fast)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from hsa_common.launcher import LaunchFile, Process
from tests.ros.conftest import start_process, stop_process, wait_for_line

pytestmark = [pytest.mark.ros]

LAUNCH = Path(__file__).parents[2] / "launch_scripts"


def graph_process(graph: str, name: str, **args: str) -> Process:
    """The process ``name`` of a launch graph resolved with ``args``."""
    return next(p for p in LaunchFile(LAUNCH / graph, args).processes() if p.name == name)


def start_ready(proc: Process, timeout: float = 180.0) -> None:
    """Start the graph's command line of a node and wait until it logs ready; stop it again."""
    started = start_process(proc.cmd)
    try:
        wait_for_line(started, "ready", timeout=timeout)
    finally:
        assert stop_process(started) == 0


@pytest.mark.parametrize(
    ("graph", "args"),
    [
        ("real.launch.yaml", {}),
        ("replay.launch.yaml", {"bag": "/tmp/unused_bag"}),
        ("sim.launch.yaml", {"markers": "true"}),
    ],
)
def test_marker_node_starts_with_its_graphs_parameters(graph: str, args: dict[str, str]) -> None:
    """It was given the kinematics node's parameter file and refused to start ('gap_factor' is not
    its parameter)."""
    start_ready(graph_process(graph, "marker_node", **args))


@pytest.mark.parametrize("trajectory", ["steps", "circle"])
def test_sequencer_starts_with_an_integer_setpoint_rate(trajectory: str) -> None:
    """setpoint_rate:=2 (an integer) killed it with "expecting type 'DOUBLE'"; trajectory:=circle
    had no config file."""
    proc = graph_process(
        "sim.launch.yaml", "setpoint_sequencer", trajectory=trajectory, setpoint_rate="2"
    )
    assert "rate:=2" in proc.cmd
    start_ready(proc)


def test_a_node_that_refuses_to_start_stops_the_graph_at_once(tmp_path: Path) -> None:
    """controller_node refusing its law: the launcher stops the graph with its message and exit 2
    (it ran 113 s)."""
    graph = tmp_path / "fail_fast.launch.yaml"
    graph.write_text(
        "launch:\n"
        "- node: {pkg: hsa_mocap_bridge, exec: mocap_bridge, name: mocap_bridge, namespace: hsa}\n"
        "- node:\n"
        "    pkg: hsa_controller_node\n    exec: controller_node\n    name: controller_node\n    "
        "namespace: hsa\n"
        "    param:\n    - {name: controller, value: pdi}\n"
    )
    started = time.monotonic()
    proc = start_process([sys.executable, "-m", "hsa_common.launcher", str(graph)])
    try:
        output, _ = proc.communicate(timeout=180.0)
    finally:
        stop_process(proc)
    elapsed = time.monotonic() - started
    errors = [line for line in output.splitlines() if line.startswith("[launch] error:")]
    assert proc.returncode == 2, output[-3000:]
    assert (
        len(errors) == 1
        and "controller_node exited with 2:" in errors[0]
        and "'controller'" in errors[0]
    ), output
    assert "[launch] mocap_bridge exited with 0" in output
    print(
        "FAULT | node refuses to start in a graph (controller:=pdi) | launcher stops the graph, "
        f"names the node and its FATAL line, exit 2 | graph ended {elapsed:.1f} s after launch "
        "(was: ran on without it for 113 s)"
    )

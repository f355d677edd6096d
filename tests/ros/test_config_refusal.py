"""Configuration faults (issue 6) for mocap_bridge, kinematics_node, controller_node, planner_node
and setpoint_sequencer as real processes: a parameter file with an out-of-range or ill-typed value,
or with a misspelt name, makes the node refuse to start (exit 2) naming the parameter; a malformed
YAML file too (exit 2, naming the file); an out-of-range or read-only update at run time is refused
with a reason naming the parameter, and the node keeps running with the old value."""

from __future__ import annotations

import math
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from hsa_common.launcher import find_executable
from tests.ros.conftest import ParameterClient, start_process, stop_process
from tests.ros.faults import EXECUTABLES, NodeProcess, fault, start_all

pytestmark = pytest.mark.ros

NS = "/cfg"
# node -> (a bad value in a parameter file (name, value), a misspelt parameter name)
BAD_FILES = {
    "mocap_bridge": (("max_jump", -1.0), "max_jmp"),
    "kinematics_node": (("window", 4), "windw"),  # a cubic needs a window of at least 5
    "controller_node": (("kp", "high"), "stale_timout"),  # wrong type
    "planner_node": (("max_iterations", 0), "max_iteration"),
    "setpoint_sequencer": (("radius", 0.5), "trajectori"),  # beyond the safe radius
}
# (node, parameter, refused value): range, validator and read-only refusals
UPDATES = [
    ("mocap_bridge", "max_jump", -0.5),
    ("mocap_bridge", "workspace_y", [0.18, 0.06]),
    ("kinematics_node", "gap_factor", 0.5),
    ("kinematics_node", "window", 30),
    ("controller_node", "kp", -1.0),
    ("controller_node", "gamma", 0.0),
    ("controller_node", "ee_e_on", math.nan),
    ("controller_node", "stale_timeout", 0.5),
    ("planner_node", "max_iterations", 5),
    ("setpoint_sequencer", "plan_timeout", 1.0),
]


def _cases() -> list[tuple[str, str, str, object]]:
    """(node, kind, parameter named in the refusal, file content) of every bad parameter file."""
    cases = []
    for node, ((name, value), typo) in BAD_FILES.items():
        cases.append((node, "bad value", name, {name: value}))
        cases.append((node, "misspelt name", typo, {typo: 1.0}))
    return cases


@pytest.fixture(scope="module")
def refused(tmp_path_factory) -> dict[tuple[str, str], tuple[int, str, float]]:
    """Start every node with each bad parameter file at once; (node, kind) -> (exit code, output,
    time to exit)."""
    work = tmp_path_factory.mktemp("params")
    procs: dict[tuple[str, str], tuple[subprocess.Popen, float]] = {}
    for node, kind, _, content in _cases():
        path = work / f"{node}_{kind.replace(' ', '_')}.yaml"
        path.write_text(yaml.safe_dump({"/**": {"ros__parameters": content}}))
        procs[node, kind] = _start(node, path), time.monotonic()
    broken = work / "broken.yaml"
    broken.write_text("/**:\n  ros__parameters:\n    max_jump: [0.1\n")
    procs["mocap_bridge", "malformed YAML"] = _start("mocap_bridge", broken), time.monotonic()
    results = {}
    for key, (proc, started) in procs.items():
        try:
            out, _ = proc.communicate(timeout=180.0)
        except subprocess.TimeoutExpired:
            stop_process(proc)
            out, _ = proc.communicate()
        results[key] = proc.returncode, out, time.monotonic() - started
    return results


def _start(node: str, params_file: Path) -> subprocess.Popen:
    """A node process with a parameter file, in /cfg."""
    exe = find_executable(EXECUTABLES[node], node)
    return start_process(
        [exe, "--ros-args", "-r", f"__ns:={NS}", "--params-file", str(params_file)]
    )


@pytest.mark.slow  # eleven processes importing JAX: ~40 s on a loaded 2-core machine
@pytest.mark.parametrize(
    ("node", "kind", "name", "content"),
    _cases(),
    ids=[f"{c[0]}-{c[1].replace(' ', '_')}" for c in _cases()],
)
def test_bad_parameter_file_is_refused_naming_the_parameter(
    refused, node: str, kind: str, name: str, content: object
) -> None:
    code, out, elapsed = refused[node, kind]
    assert code == 2, out[-3000:]
    assert "refusing to start" in out and f"'{name}'" in out, out[-3000:]
    fault(
        f"{node} parameter file with {kind} ({name})",
        "refused at start, exit 2, parameter named",
        "n/a (fix the file)",
    )


@pytest.mark.slow
def test_malformed_parameter_file_stops_the_node(refused) -> None:
    code, out, _ = refused["mocap_bridge", "malformed YAML"]
    assert code == 2 and "ready" not in out and "Traceback" not in out, out[-3000:]
    assert (
        "refusing to start" in out and "Couldn't parse params file" in out and "broken.yaml" in out
    ), out[-3000:]


@pytest.fixture(scope="module")
def running() -> Iterator[dict[str, NodeProcess]]:
    """The five nodes with valid parameters in /cfg (the sequencer waits an hour before its first
    point)."""
    args = ["-r", f"__ns:={NS}"]
    procs = start_all(
        {
            node: (
                node,
                [*args, *(["-p", "start_delay:=3600.0"] if node == "setpoint_sequencer" else [])],
            )
            for node in BAD_FILES
        }
    )
    yield procs
    assert {key: proc.stop() for key, proc in procs.items()} == dict.fromkeys(procs, 0)


@pytest.mark.parametrize(
    ("node", "name", "value"), UPDATES, ids=[f"{n}-{p}" for n, p, _ in UPDATES]
)
def test_refused_update_keeps_the_node_running_with_the_old_value(
    running, ros_node, node: str, name: str, value: object
) -> None:
    params = ParameterClient(ros_node, f"{NS}/{node}")
    old = params.get(name)
    t0 = time.monotonic()
    result = params.set(name, value)
    answered = time.monotonic() - t0
    assert not result.successful and name in result.reason, result.reason
    assert params.get(name) == old
    time.sleep(0.2)
    assert running[node].proc.poll() is None, f"{node} exited after a refused update"
    fault(
        f"{node} run-time update {name} := {value!r}",
        f"refused ('{result.reason[:70]}'), old value {old!r} kept",
        answered,
    )

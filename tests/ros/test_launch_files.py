"""Launch graphs: every file in launch_scripts/ resolves (executables, packages, parameter files), and the launcher
refuses malformed invocations with a clear message."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from hsa_common.launcher import LaunchError, LaunchFile, main

GRAPHS = sorted((Path(__file__).parents[2] / "launch_scripts").glob("*.launch.yaml"))
REQUIRED = {"replay.launch.yaml": {"bag": "/tmp/some_bag"}}


@pytest.mark.parametrize("graph", GRAPHS, ids=lambda p: p.name)
def test_graph_resolves(graph: Path) -> None:
    procs = LaunchFile(graph, REQUIRED.get(graph.name, {})).processes()
    assert procs, f"{graph.name} starts nothing"
    for proc in procs:
        assert os.access(proc.cmd[0], os.X_OK), f"{proc.name}: {proc.cmd[0]} is not executable"
        files = [proc.cmd[i + 1] for i, arg in enumerate(proc.cmd) if arg == "--params-file"]
        assert all(Path(f).is_file() for f in files), files
        if "--ros-args" in proc.cmd:
            assert f"__ns:=/hsa" in proc.cmd, f"{proc.name} is not in the /hsa namespace"


def test_names_of_the_sim_graph() -> None:
    names = [p.name for p in LaunchFile(GRAPHS[0].with_name("sim.launch.yaml"), {}).processes()]
    assert names == ["sim_node", "dynamixel_driver", "mocap_bridge", "kinematics_node", "planner_node",
                     "controller_node", "setpoint_sequencer", "bag_recorder"]
    no_bag = [p.name for p in LaunchFile(GRAPHS[0].with_name("sim.launch.yaml"), {"record": "false"}).processes()]
    assert "bag_recorder" not in no_bag


def test_bad_invocations_are_refused(tmp_path, capsys) -> None:
    sim = GRAPHS[0].with_name("sim.launch.yaml")
    with pytest.raises(LaunchError, match="unknown launch argument"):
        LaunchFile(sim, {"materail": "fpu"})
    with pytest.raises(LaunchError, match="'bag' has no default"):
        LaunchFile(sim.with_name("replay.launch.yaml"), {})
    with pytest.raises(LaunchError, match="is not a boolean"):
        LaunchFile(sim, {"record": "maybe"}).processes()
    broken = tmp_path / "broken.launch.yaml"
    broken.write_text("launch:\n- node: {pkg: hsa_no_such_package, exec: x}\n")
    assert main([str(broken)]) == 2
    assert "hsa_no_such_package" in capsys.readouterr().err

"""Launch graphs: every file in launch_scripts/ resolves (executables, packages, parameter files),
every parameter a graph gives a node is one of that node's, every node starts from lib/<pkg>/<exe>
as under ros2 launch, and the launcher refuses what the real launch_yaml parser refuses (and what it
does not implement) with a clear message."""

from __future__ import annotations

import importlib
import os
import sys
from importlib.metadata import distribution
from pathlib import Path

import pytest
import yaml

from hsa_common.compose import parse_entries, split_parameters
from hsa_common.launcher import LaunchError, LaunchFile, Process, main
from hsa_common.parameters import RUNNER_PARAMS

GRAPHS = sorted((Path(__file__).parents[2] / "launch_scripts").glob("*.launch.yaml"))
REQUIRED = {"replay.launch.yaml": {"bag": "/tmp/some_bag"}}
OPTIONAL_ON = {
    "sim.launch.yaml": [{"markers": "true", "live": "true"}, {"compose": "false"}],
    "real.launch.yaml": [{"live": "true"}],
    "replay.launch.yaml": [{"record": "true"}],
    "identify.launch.yaml": [{"sim": "true"}, {"sim": "false"}, {"clock": "lockstep"}],
}
"""Launch arguments that switch every optional node of a graph on (or each branch of it)."""
PACKAGES = (
    "hsa_core",
    "hsa_common",
    "hsa_mocap_bridge",
    "hsa_kinematics_node",
    "hsa_planner_node",
    "hsa_controller_node",
    "hsa_dynamixel_driver",
    "hsa_sim_node",
    "hsa_bag",
    "hsa_identification",
    "hsa_live",
)


@pytest.mark.parametrize("graph", GRAPHS, ids=lambda p: p.name)
def test_graph_resolves(graph: Path) -> None:
    procs = LaunchFile(graph, REQUIRED.get(graph.name, {})).processes()
    assert procs, f"{graph.name} starts nothing"
    for proc in procs:
        assert os.access(proc.cmd[0], os.X_OK), f"{proc.name}: {proc.cmd[0]} is not executable"
        files = [proc.cmd[i + 1] for i, arg in enumerate(proc.cmd) if arg == "--params-file"]
        assert all(Path(f).is_file() for f in files), files
        if "--ros-args" in proc.cmd:
            assert "__ns:=/hsa" in proc.cmd, f"{proc.name} is not in the /hsa namespace"


def _composed(proc: Process) -> list[str]:
    """The names of the nodes a process runs (several under hsa_compose)."""
    if Path(proc.cmd[0]).name != "hsa_compose":
        return [proc.name]
    return [e.name for e in parse_entries(proc.cmd[1 : proc.cmd.index("--ros-args")])[0]]


def test_names_of_the_sim_graph() -> None:
    """Lockstep (compose:=true, the default): simulator + bridge and kinematics + controller +
    recorder composed; compose:=false, and the wall clock: one process per node."""
    sim = GRAPHS[0].with_name("sim.launch.yaml")
    for args in ({}, {"compose": "true"}):
        layout = [_composed(p) for p in LaunchFile(sim, args).processes()]
        assert layout == [
            ["sim_node", "mocap_bridge"],
            ["kinematics_node", "controller_node", "bag_recorder"],
            ["dynamixel_driver"],
            ["planner_node"],
            ["setpoint_sequencer"],
        ], args
    for args in ({"compose": "false"}, {"clock": "wall"}, {"clock": "wall", "compose": "true"}):
        names = [p.name for p in LaunchFile(sim, args).processes()]
        assert names == [
            "sim_node",
            "dynamixel_driver",
            "mocap_bridge",
            "kinematics_node",
            "planner_node",
            "controller_node",
            "setpoint_sequencer",
            "bag_recorder",
        ], args
    for args in ({"record": "false"}, {"record": "false", "compose": "false"}):
        nodes = [n for p in LaunchFile(sim, args).processes() for n in _composed(p)]
        assert "bag_recorder" not in nodes and len(nodes) == 7, args


def test_names_of_the_identify_graph() -> None:
    """Simulated in lockstep (compose:=true, the default): simulator + bridge and kinematics +
    calibration + recorder composed; compose:=false, the wall clock and the real robot: one process
    per node."""
    identify = GRAPHS[0].with_name("identify.launch.yaml")
    layout = [_composed(p) for p in LaunchFile(identify, {"clock": "lockstep"}).processes()]
    assert layout == [
        ["sim_node", "mocap_bridge"],
        ["kinematics_node", "calibration_node", "bag_recorder"],
        ["dynamixel_driver"],
        ["excitation_player"],
    ]
    alone = ["dynamixel_driver", "mocap_bridge", "kinematics_node", "calibration_node"]
    alone += ["excitation_player", "bag_recorder"]
    for args in (
        {"clock": "lockstep", "compose": "false"},
        {},
        {"sim": "false", "clock": "lockstep"},
    ):
        names = [p.name for p in LaunchFile(identify, args).processes()]
        assert names == (["sim_node"] if args.get("sim") != "false" else []) + alone, args
    nodes = [
        n
        for p in LaunchFile(identify, {"clock": "lockstep", "record": "false"}).processes()
        for n in _composed(p)
    ]
    assert "bag_recorder" not in nodes and len(nodes) == 6


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


def _given_parameters(proc: Process) -> set[str]:
    """Names of the parameters a launch entry gives its node: the keys of the parameter-file
    sections that match it (``/**`` or ``…/<node name>``) and its -p overrides; ``use_sim_time`` and
    the runner's parameters (``lockstep``), which every node accepts, are left out."""
    names = set()
    for flag, value in zip(proc.cmd, proc.cmd[1:]):
        if flag == "--params-file":
            for key, section in (yaml.safe_load(Path(value).read_text()) or {}).items():
                if key == "/**" or key.rsplit("/", 1)[-1] == proc.name:
                    names.update((section or {}).get("ros__parameters", {}) or {})
        elif flag == "-p":
            names.add(value.split(":=", 1)[0])
    return names - {"use_sim_time"} - RUNNER_PARAMS


def _composed_parameters(proc: Process) -> dict[str, set[str]]:
    """Per node of an hsa_compose process, the names of the parameters it is given (as
    :func:`_given_parameters`; the ``/**`` parameters every node of the process gets: ``*``)."""
    entries, files, left_out = parse_entries(proc.cmd[1 : proc.cmd.index("--ros-args")])
    names = [e.name for e in entries]
    ros_args = proc.cmd[proc.cmd.index("--ros-args") + 1 :]
    rest, per_node = split_parameters(ros_args, names + left_out, files)
    given = {name: set(per_node.get(name, {})) for name in names}
    given["*"] = _given_parameters(Process("*", ["hsa_compose", *rest], False))
    for flag, value in zip(rest, rest[1:]):
        if flag == "--params-file":
            for key, section in (yaml.safe_load(Path(value).read_text()) or {}).items():
                if key.rsplit("/", 1)[-1] in given and key != "/**":
                    params = (section or {}).get("ros__parameters", {}) or {}
                    given[key.rsplit("/", 1)[-1]].update(params)
            if Path(value).name.startswith("hsa_compose_"):
                os.unlink(value)
    return {name: names - {"use_sim_time"} - RUNNER_PARAMS for name, names in given.items()}


def _node_specs(executable: str) -> set[str] | None:
    """The parameter names the console script lib/<pkg>/<exe> declares (its module's SPECS), None if
    it has none."""
    exe = Path(executable)
    entry = next(
        e
        for e in distribution(exe.parent.name).entry_points.select(group="console_scripts")
        if e.name == exe.name
    )
    specs = getattr(importlib.import_module(entry.module), "SPECS", None)
    return None if specs is None else {s.name for s in specs}


@pytest.mark.parametrize("graph", GRAPHS, ids=lambda p: p.name)
def test_every_parameter_a_graph_gives_is_one_of_the_nodes(graph: Path) -> None:
    """A name the node does not declare makes it refuse to start (e.g. the kinematics file given to
    marker_node)."""
    checked = 0
    for extra in OPTIONAL_ON[graph.name]:
        for proc in LaunchFile(graph, {**REQUIRED.get(graph.name, {}), **extra}).processes():
            if Path(proc.cmd[0]).name == "hsa_compose":
                given = _composed_parameters(proc)
                common = given.pop("*")
                assert not common, f"{graph.name}: every composed node is given {common}"
                entries = parse_entries(proc.cmd[1 : proc.cmd.index("--ros-args")])[0]
                for entry in entries:
                    declared = {s.name for s in importlib.import_module(entry.module).SPECS}
                    unknown = given[entry.name] - declared
                    assert not unknown, f"{graph.name}: {entry.name} is given {sorted(unknown)}"
                    checked += 1
                continue
            declared = _node_specs(proc.cmd[0])
            if declared is None:
                continue  # bag_player: a CLI with argparse options, no node parameters
            unknown = _given_parameters(proc) - declared
            assert not unknown, (
                f"{graph.name}: {proc.name} is given {sorted(unknown)}, which it does not declare"
            )
            checked += 1
    assert checked >= 5


@pytest.mark.parametrize("graph", GRAPHS, ids=lambda p: p.name)
def test_nodes_start_from_lib_pkg_exe_like_ros2_launch(graph: Path) -> None:
    """ros2 launch runs <prefix>/lib/<pkg>/<exe>; nothing is started by name from PATH (bag_player
    was)."""
    for extra in OPTIONAL_ON[graph.name]:
        for proc in LaunchFile(graph, {**REQUIRED.get(graph.name, {}), **extra}).processes():
            exe = Path(proc.cmd[0])
            assert exe.parent.parent.name == "lib" and exe.parent.name in PACKAGES, (
                f"{proc.name}: {exe}"
            )


def test_every_console_script_is_installed_where_ros2_run_looks() -> None:
    """The bootstrap lays the venv out like a colcon install: lib/<pkg>/<exe> for every console
    script."""
    for package in PACKAGES:
        scripts = [
            e.name for e in distribution(package).entry_points.select(group="console_scripts")
        ]
        assert scripts, package
        for name in scripts:
            exe = Path(sys.prefix, "lib", package, name)
            assert exe.is_file() and os.access(exe, os.X_OK), f"{exe} missing"


@pytest.mark.parametrize(
    "graph", [g for g in GRAPHS if "{name: trajectory," in g.read_text()], ids=lambda p: p.name
)
def test_every_offered_trajectory_has_its_sequencer_file(graph: Path) -> None:
    """trajectory:=circle was offered without config/circle.yaml; a trajectory outside the choices
    is refused."""
    spec = next(
        a["arg"]
        for a in yaml.safe_load(graph.read_text())["launch"]
        if "arg" in a and a["arg"]["name"] == "trajectory"
    )
    choices = [c["value"] for c in spec["choice"]]
    assert {"steps", "star", "circle", "contour"} <= set(choices)
    for trajectory in choices:
        procs = LaunchFile(graph, {"trajectory": trajectory}).processes()
        sequencer = next(p for p in procs if p.name == "setpoint_sequencer")
        files = [Path(v) for f, v in zip(sequencer.cmd, sequencer.cmd[1:]) if f == "--params-file"]
        assert any(f.name == f"{trajectory}.yaml" and f.is_file() for f in files), sequencer.cmd
    with pytest.raises(LaunchError, match="trajectory:=ellipse is not one of"):
        LaunchFile(graph, {"trajectory": "ellipse"})


NODE = "  pkg: hsa_mocap_bridge\n  exec: mocap_bridge\n  name: bridge\n"


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("  parameters: []\n", "Unexpected key(s) found in 'node'"),  # launch_yaml's own words
        ("  exe: mocap_bridge\n", "Unexpected key(s) found in 'node'"),
        (
            "  respawn: 'true'\n",
            "key 'respawn' of 'node' is valid for ros2 launch but not implemented by hsa_launch",
        ),
        (
            "  launch-prefix: gdb\n",
            "key 'launch-prefix' of 'node' is valid for ros2 launch but not implemented",
        ),
        ("  output: log\n", "implements output 'screen' only"),
        ("  on_exit: restart\n", "on_exit must be 'shutdown'"),
        ("  param:\n  - {name: max_age, valeu: 0.0}\n", "param entry"),
    ],
)
def test_node_entries_are_checked_against_the_launch_yaml_schema(
    tmp_path: Path, extra: str, message: str
) -> None:
    """A file hsa_launch accepts must be one ros2 launch accepts: unknown keys refused,
    unimplemented ones named."""
    graph = tmp_path / "g.launch.yaml"
    graph.write_text(
        "launch:\n- node:\n" + "\n".join("  " + line for line in (NODE + extra).splitlines()) + "\n"
    )
    with pytest.raises(LaunchError) as refused:
        LaunchFile(graph, {})
    assert message in str(refused.value)
    graph.write_text(
        "launch:\n- node:\n"
        + "\n".join("  " + line for line in NODE.splitlines())
        + "\n    output: screen\n    on_exit: shutdown\n"
    )
    assert [p.name for p in LaunchFile(graph, {}).processes()] == ["bridge"]


def test_launch_argument_outside_its_choices_is_refused_in_one_line(capsys) -> None:
    """controller:=pdi is refused before anything starts (ros2 launch checks arg choices the same
    way)."""
    assert main([str(GRAPHS[0].with_name("sim.launch.yaml")), "controller:=pdi"]) == 2
    err = capsys.readouterr().err
    assert (
        err.count("\n") == 1
        and "controller:=pdi is not one of ['psatid', 'psatid_gc', 'pid']" in err
    )

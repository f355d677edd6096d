"""The two layouts of sim.launch.yaml and of identify.launch.yaml (lockstep simulation) give every
node the same parameters: for every launch argument, the (node, parameter) pairs it reaches with one
process per node are the ones it reaches with ``compose:=true`` (hsa_compose), with the same values.
Read from the command lines the project's launcher builds, as rcl and hsa_compose resolve them; no
graph is started."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
import yaml

from hsa_common import compose
from hsa_common.launcher import LaunchFile, Process, package_share

LAUNCH = Path(__file__).parents[2] / "launch_scripts"
LAYOUT_ARGS = {"compose", "clock", "sim"}
"""Arguments that choose the layout itself (on the wall clock, and with the real robot, both
layouts are the same)."""
BASE = {
    "sim.launch.yaml": {"markers": "true", "live": "true"},
    "identify.launch.yaml": {"clock": "lockstep"},
}
"""Per graph, the arguments of its composed layout: the optional nodes on (so that their
arguments, e.g. ``live_port``, reach them), and the clock that composes."""
REAL_ONLY = {"sim.launch.yaml": set(), "identify.launch.yaml": {"port"}}
"""Per graph, the arguments of the real robot's nodes alone (sim:=false): none of the simulation."""
NODES = {"sim.launch.yaml": 8, "identify.launch.yaml": 7}
"""Nodes of each graph with :data:`BASE`'s arguments, optional nodes off."""
Parameters = dict[str, dict[str, Any]]
"""Per node (namespace/name), its parameters by dotted name."""


def _values(tmp_path: Path) -> dict[str, str]:
    """A value other than the default (or :data:`BASE`'s) for each launch argument that is not a
    choice."""
    clock = tmp_path / "clock.yaml"
    lockstep = yaml.safe_load(
        (package_share("hsa_sim_node") / "config/clock_lockstep.yaml").read_text()
    )
    clock.write_text(yaml.safe_dump({**lockstep, "/**/sim_node": {"ros__parameters": {"seed": 3}}}))
    return {
        "ee_integral": "true",
        "rate": "27.8",
        "integrator_dt": "0.036",
        "sigma_a_eq": "[0.98, 1.01]",
        "plant_sigma_a_eq": "[1.03, 1.02]",
        "payload": "0.05",
        "command_latency": "0.012",
        "command_queue_depth": "10",
        "command_transaction": "0.016",
        "gains": str(package_share("hsa_core") / "config/gains/fpu_pid.yaml"),
        "sequencer_config": str(package_share("hsa_planner_node") / "config/star.yaml"),
        "setpoint_rate": "2.0",
        "markers": "false",
        "live": "false",
        "live_port": "8766",
        "record": "false",
        "bag_dir": str(tmp_path / "bags") + "/",
        "clock_config": str(clock),
        "duration": "12.5",
        "seed": "4",
        "n_levels": "3",
        "hold": "4.5",
        "start_delay": "1.5",
        "final_hold": "0.5",
        "robot_params": str(tmp_path / "robot.yaml"),
        "payload_schedule": "[0.0, 0.0, 2.0, 0.2]",
        "topics": "[/hsa/ee_pose, /hsa/phi_cmd]",
    }


def _resolve(name: str, ros_args: list[str]) -> tuple[str, dict[str, Any]]:
    """Node ``name``'s namespace/name and parameters under ``ros_args``: the matching sections of
    the parameter files in order (``/**``, ``/**/name``, ``/ns/name``), then the ``-p`` rules."""
    namespace, files, rules = "/", [], []
    for flag, value in zip(ros_args, ros_args[1:]):
        if flag == "-r" and value.startswith("__ns:="):
            namespace = value.partition(":=")[2]
        elif flag == "-r" and value.startswith("__node:="):
            name = value.partition(":=")[2]
        elif flag == "--params-file":
            files.append(value)
        elif flag == "-p":
            rules.append(value)
    params: dict[str, Any] = {}
    for file in files:
        for key, section in (yaml.safe_load(Path(file).read_text()) or {}).items():
            if key in ("/**", f"/**/{name}", f"{namespace.rstrip('/')}/{name}"):
                params.update(compose.common_parameters({"/**": section}))
    for rule in rules:
        key, _, value = rule.partition(":=")
        params[key] = yaml.safe_load(value)
    return f"{namespace.rstrip('/')}/{name}", params


def _parameters(graph: str, args: dict[str, str]) -> Parameters:
    """Every node of launch file ``graph`` with ``args``, and its parameters."""
    nodes: Parameters = {}
    for proc in LaunchFile(LAUNCH / graph, args).processes():
        ros_args = proc.cmd[proc.cmd.index("--ros-args") + 1 :]
        if Path(proc.cmd[0]).name != "hsa_compose":
            name, params = _resolve(proc.name, ros_args)
            nodes[name] = params
            continue
        nodes.update(_composed(proc, ros_args))
    return nodes


def _composed(proc: Process, ros_args: list[str]) -> Parameters:
    """The nodes of an hsa_compose process, resolved as hsa_compose's main hands them to rclpy."""
    start = len(compose.WRITTEN)  # other tests of this process may have left their own entries
    entries, files, left_out = compose.parse_entries(proc.cmd[1 : proc.cmd.index("--ros-args")])
    names = [e.name for e in entries]
    kept, per_node = compose.split_parameters(ros_args, names + left_out, files)
    mine = {name: params for name, params in per_node.items() if name in names}
    kept += ["--params-file", compose.node_file(mine)]
    try:
        return dict(_resolve(name, kept) for name in names)
    finally:
        for path in compose.WRITTEN[start:]:
            os.unlink(path)
        del compose.WRITTEN[start:]


def _reached(base: Parameters, varied: Parameters) -> set[tuple[str, str]]:
    """The (node, parameter) pairs that differ (a node that appears or goes: (node, ``*``))."""
    pairs = {(node, "*") for node in set(base) ^ set(varied)}
    for node in set(base) & set(varied):
        a, b = base[node], varied[node]
        pairs |= {(node, p) for p in set(a) | set(b) if a.get(p, a) != b.get(p, b)}
    return pairs


@pytest.mark.parametrize("graph", sorted(BASE))
def test_both_layouts_give_every_node_the_same_parameters(graph: str) -> None:
    args = {k: v for k, v in BASE[graph].items() if k in LAYOUT_ARGS}
    separate = _parameters(graph, {**args, "compose": "false"})
    composed = _parameters(graph, {**args, "compose": "true"})
    assert len(separate) == NODES[graph]
    differ = sorted(_reached(separate, composed))
    assert not differ, f"(node, parameter) given differently under compose:=true: {differ}"


@pytest.mark.parametrize("graph", sorted(BASE))
def test_every_launch_argument_reaches_the_same_parameters_in_both_layouts(
    graph: str, tmp_path
) -> None:
    spec = yaml.safe_load((LAUNCH / graph).read_text())["launch"]
    declared = {a["arg"]["name"]: a["arg"] for a in spec if "arg" in a}
    values = _values(tmp_path)
    (tmp_path / "robot.yaml").write_text(
        yaml.safe_dump({"/**": {"ros__parameters": {"params_file": "/tmp/robot_set.yaml"}}})
    )
    on = BASE[graph]
    base = {layout: _parameters(graph, {**on, "compose": layout}) for layout in ("false", "true")}
    for name, arg in declared.items():
        if name in LAYOUT_ARGS | REAL_ONLY[graph]:
            continue
        choices = [c["value"] for c in arg.get("choice", [])]
        value = next((c for c in choices if c != arg["default"]), values.get(name))
        assert value is not None, f"no test value for launch argument '{name}': add one"
        varied = {
            layout: _parameters(graph, {**on, "compose": layout, name: value}) for layout in base
        }
        reached = {layout: _reached(base[layout], varied[layout]) for layout in base}
        assert reached["false"], f"{name}:={value} reaches no node"
        assert reached["true"] == reached["false"], (
            f"{name}:={value}: only separate {sorted(reached['false'] - reached['true'])}, "
            f"only composed {sorted(reached['true'] - reached['false'])}"
        )
        differ = sorted(_reached(varied["false"], varied["true"]))
        assert not differ, f"{name}:={value}: given differently under compose:=true: {differ}"

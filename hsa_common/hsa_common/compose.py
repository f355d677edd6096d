"""``hsa_compose``: several hsa-ros nodes in one process, one rclpy context (one DDS participant)
and one executor.

The rclpy analogue of a component container, chosen in the launch file: the node classes are the
same, unchanged, and each still runs alone under ``ros2 run``. The command line (a launch file's
``node`` with ``exec: hsa_compose`` and ``args`` builds it)::

    hsa_compose NAME=MODULE:CLASS [NAME@FILE ...] [NAME=MODULE:CLASS ...] [NAME=]
                --ros-args [-r __ns:=/hsa] [--params-file F] [-p P:=V]

``NAME`` is the node's own name (its class gives it; a mismatch is refused at start). Remappings and
parameters of the ROS arguments reach every node of the process, as rcl applies them to each node,
and our nodes refuse a parameter they do not declare: a ``/**`` parameter must be one every composed
node declares (``use_sim_time``, ``lockstep``), and a file section keyed ``/**/NAME`` reaches node
``NAME`` alone (``clock_lockstep.yaml`` has such sections). Parameters of one node:

* ``NAME@FILE``: the ``/**`` section of parameter file ``FILE`` (the node's usual file, e.g. the
  controller's material file);
* a parameter named ``NAME.param`` (``-p sim_node.material:=fpu``, or the same name in a ``/**``
  section of a parameter file: a launch file's ``{name: sim_node.material, value: fpu}`` becomes
  that under ``ros2 launch``) is its ``param``. Files first, in order, then these.

``NAME=`` leaves node ``NAME`` out of this run and drops its parameters (a launch file's optional
node: the recorder with ``record:=false``). The ``node`` entry must not have a ``name``: it would
rename every node of the process.

Lifetime (:func:`hsa_common.runner.run_nodes`): signals, parent death and the teardown bound hold
for the process as for one node; the nodes' ``on_shutdown`` hooks run in command-line order; a node
that shuts the context down (the sequencer at the end of its trajectory) stops them all. In lockstep
each node is a participant of its own.
"""

from __future__ import annotations

import importlib
import os
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import yaml
from rclpy.node import Node

from hsa_common.parameters import ParameterValidationError
from hsa_common.runner import run_nodes
from hsa_core.jaxsetup import configure_jax

USAGE = "usage: hsa_compose NAME=MODULE:CLASS [NAME@FILE] [NAME=] ... [--ros-args ...]"
WRITTEN: list[str] = []
"""Temporary parameter files this process wrote (removed once rclpy has read them)."""


class ComposeError(ParameterValidationError):
    """A malformed command line: the message is the one-line refusal."""


@dataclass(frozen=True)
class Entry:
    """One composed node: its name and ``module:Class``."""

    name: str
    module: str
    cls: str


def parse_entries(
    words: Sequence[str],
) -> tuple[list[Entry], list[tuple[str, str]], list[str]]:
    """``NAME=MODULE:CLASS``, ``NAME@FILE`` and ``NAME=`` words → the entries (distinct names), the
    (name, file) pairs and the names left out; or :class:`ComposeError`."""
    files = []
    for word in words:
        name, at, path = word.partition("@")
        if at and "=" not in name:
            files.append((name, path))
    entries, left_out = [], []
    for word in (w for w in words if "@" not in w.partition("=")[0]):
        name, _, target = word.partition("=")
        if name.isidentifier() and word == f"{name}=":
            left_out.append(name)
            continue
        module, _, cls = target.partition(":")
        if not (name and module and cls) or not name.isidentifier():
            raise ComposeError(f"'{word}' is not NAME=MODULE:CLASS; {USAGE}")
        entries.append(Entry(name, module, cls))
    if not entries:
        raise ComposeError(f"no node given; {USAGE}")
    names = [e.name for e in entries] + left_out
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ComposeError(f"node names given twice: {twice}")
    strays = sorted({n for n, _ in files} - {e.name for e in entries})
    if strays:
        raise ComposeError(f"parameter files given for nodes not composed: {strays}")
    missing = [f for _, f in files if not os.path.isfile(f)]
    if missing:
        raise ComposeError(f"parameter file {missing[0]} does not exist")
    return entries, files, left_out


def split_parameters(
    ros_args: Sequence[str],
    names: Sequence[str],
    node_files: Sequence[tuple[str, str]] = (),
) -> tuple[list[str], dict[str, dict[str, Any]]]:
    """Split the parameters of the composed nodes ``names`` out of the ROS arguments.

    Returns the ROS arguments without the ``-p NAME.param:=value`` rules, each parameter file whose
    ``/**`` section holds ``NAME.param`` entries replaced by a copy without them (a temporary file),
    and per node its parameters: the ``/**`` section of each of its ``node_files`` ((name, path)
    pairs, in order), then its prefixed parameters in command-line order (later ones win)."""
    kept: list[str] = []
    per_node: dict[str, dict[str, Any]] = {}
    for name, path in node_files:
        per_node.setdefault(name, {}).update(common_parameters(_read(path)))
    words = iter(ros_args)
    for word in words:
        if word in ("-p", "--param"):
            rule = next(words, "")
            key, _, value = rule.partition(":=")
            node, _, param = key.partition(".")
            if node in names and param:
                per_node.setdefault(node, {})[param] = yaml.safe_load(value)
                continue
            kept += [word, rule]
        elif word == "--params-file":
            path = next(words, "")
            doc = _read(path)
            common = common_parameters(doc)
            mine = {
                k: v
                for k, v in common.items()
                if k.partition(".")[0] in names and k.partition(".")[2]
            }
            for key, value in mine.items():
                node, _, param = key.partition(".")
                per_node.setdefault(node, {})[param] = value
            if mine:
                doc["/**"]["ros__parameters"] = {k: v for k, v in common.items() if k not in mine}
                path = _write(doc)
            kept += [word, path]
        else:
            kept.append(word)
    return kept, per_node


def _read(path: str) -> dict[str, Any]:
    """A parameter file's sections ({} if it cannot be read: rcl refuses it in its own words)."""
    try:
        with open(path, encoding="utf8") as stream:
            doc = yaml.safe_load(stream)
    except (OSError, yaml.YAMLError):
        return {}
    return doc if isinstance(doc, dict) else {}


def common_parameters(doc: dict[str, Any]) -> dict[str, Any]:
    """The parameters of a file's ``/**`` section, by dotted name (as rcl reads nested mappings)."""
    section = doc.get("/**")
    params = section.get("ros__parameters") if isinstance(section, dict) else None
    return dict(_flatten(params, "")) if isinstance(params, dict) else {}


def _flatten(params: Any, prefix: str) -> Iterator[tuple[str, Any]]:
    """(dotted name, value) pairs of a nested mapping."""
    if not isinstance(params, dict):
        yield prefix, params
        return
    for key, value in params.items():
        yield from _flatten(value, f"{prefix}.{key}" if prefix else str(key))


def node_file(per_node: dict[str, dict[str, Any]]) -> str:
    """A parameter file with one ``/**/NAME`` section per node (a temporary file; its path)."""
    return _write({f"/**/{name}": {"ros__parameters": p} for name, p in per_node.items()})


def _write(doc: dict[str, Any]) -> str:
    """``doc`` as a temporary parameter file (listed in :data:`WRITTEN`); its path."""
    fd, path = tempfile.mkstemp(prefix="hsa_compose_", suffix=".yaml")
    with os.fdopen(fd, "w", encoding="utf8") as stream:
        yaml.safe_dump(doc, stream)
    WRITTEN.append(path)
    return path


def factory(entry: Entry) -> Callable[[], Node]:
    """The node class of ``entry`` as a factory that checks the node's name."""
    cls = getattr(importlib.import_module(entry.module), entry.cls, None)
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise ComposeError(f"{entry.module}:{entry.cls} is not an rclpy Node class")

    def make() -> Node:
        node = cls()
        if node.get_name() != entry.name:
            raise ComposeError(
                f"{entry.module}:{entry.cls} created node '{node.get_name()}', not '{entry.name}'"
            )
        return node

    return make


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point ``hsa_compose``."""
    words = list(sys.argv[1:] if argv is None else argv)
    cut = words.index("--ros-args") if "--ros-args" in words else len(words)
    try:
        entries, files, left_out = parse_entries(words[:cut])
        factories = [factory(e) for e in entries]
    except (ComposeError, ImportError) as exc:
        print(f"hsa_compose: refusing to start: {exc}", file=sys.stderr)
        return 2
    names = [e.name for e in entries]
    ros_args, per_node = split_parameters(words[cut + 1 :], names + left_out, files)
    args = [sys.argv[0], "--ros-args", *ros_args]
    mine = {name: params for name, params in per_node.items() if name in names}
    if mine:
        args += ["--params-file", node_file(mine)]
    first = factories[0]

    def clean_then_make() -> Node:
        for path in WRITTEN:  # rclpy.init has read them
            os.unlink(path)
        return first()

    factories[0] = clean_then_make
    configure_jax()  # the model nodes compute in float64 (as each node's own main does)
    return run_nodes(factories, "hsa_compose", args)

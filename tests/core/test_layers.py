"""hsa_core's parts stay in layers: a part imports only parts below it (docs/core_api.md, "The
parts"), and no module imports another part's private (``_``) names."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "hsa_core" / "hsa_core"
LAYERS = [
    "model",
    "sensing",
    "task",
    "driver",
    "controller",
    "runs",
    "analysis",
    "sim",
    "sysid",
    "apps",
]
"""Lowest first; the top-level modules (jaxsetup, resultcache, refusal, rate_meter, cli) are shared
and checked by the module import graph having no circle."""


def part_of(module: str) -> str | None:
    """The part of a dotted hsa_core module name, or None for a top-level module."""
    names = module.split(".")
    return names[1] if len(names) > 2 and names[1] in LAYERS else None


def imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module, imported names) of every absolute hsa_core import in the file, nested ones too."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module.split(".")[0] == "hsa_core":
                names = [alias.name for alias in node.names]
                submodules = [f"{node.module}.{n}" for n in names]
                found += [(node.module, names)] + [(m, []) for m in submodules]
        elif isinstance(node, ast.Import):
            found += [(a.name, []) for a in node.names if a.name.split(".")[0] == "hsa_core"]
    return found


def module_name(path: Path) -> str:
    return ".".join(("hsa_core", *path.relative_to(PACKAGE).with_suffix("").parts))


def test_every_part_is_a_layer_and_every_module_is_in_one_or_shared() -> None:
    parts = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert parts == set(LAYERS)


def test_no_part_imports_a_part_above_it_or_a_private_name_of_another() -> None:
    upward, private = [], []
    for path in sorted(PACKAGE.rglob("*.py")):
        here = part_of(module_name(path))
        for module, names in imports(path):
            there = part_of(module)
            if here and there and LAYERS.index(there) > LAYERS.index(here):
                upward.append(f"{module_name(path)} imports {module}")
            if there != here and any(n.startswith("_") for n in names):
                private.append(f"{module_name(path)} imports {names} from {module}")
    assert upward == [] and private == []


def test_a_part_importing_upwards_is_found(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text("from hsa_core.sim import world\nfrom hsa_core.model.params import _build\n")
    found = imports(probe)
    assert ("hsa_core.sim.world", []) in found
    assert LAYERS.index(part_of("hsa_core.sim.world")) > LAYERS.index("model")
    assert ("hsa_core.model.params", ["_build"]) in found

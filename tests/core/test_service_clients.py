"""Every plan_setpoint client in this repository uses hsa_common.qos.SERVICE: with rclpy's default
client profile (keep last 10) a burst loses answers in the client's own histories
(docs/nodes/hsa_planner_node.md), and tests/ros/test_plan_burst.py proves the burst only for the
SERVICE profile. Reads the sources, imports nothing."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).parents[2]
TREES = [
    *REPO.glob("hsa_*"),
    *(REPO / d for d in ("tests", "tools", "launch_scripts", "benchmarks")),
]
"""Where our sources are (out/, build/ and .venv/ hold none)."""
# measures rclpy's default on request
DELIBERATE = {REPO / "tests" / "ros" / "peers" / "plan_burst_peer.py"}


def plan_clients(path: Path) -> list[ast.Call]:
    """The ``create_client(PlanSetpoint, ...)`` calls of one source file."""
    text = path.read_text()
    if "PlanSetpoint" not in text:
        return []
    return [
        node
        for node in ast.walk(ast.parse(text, str(path)))
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "create_client"
        and node.args
        and isinstance(node.args[0], ast.Name)
        and node.args[0].id == "PlanSetpoint"
    ]


def uses_service_profile(call: ast.Call) -> bool:
    """``qos_profile=qos.SERVICE`` is among the call's keywords."""
    return any(
        k.arg == "qos_profile" and ast.unparse(k.value) in ("qos.SERVICE", "hsa_common.qos.SERVICE")
        for k in call.keywords
    )


def test_every_plan_client_uses_the_service_profile() -> None:
    sources = [p for tree in TREES for p in tree.rglob("*.py") if p not in DELIBERATE]
    calls = [(p, c) for p in sources for c in plan_clients(p)]
    assert len(calls) >= 4  # the sequencer and the tests' clients
    wrong = [f"{p.relative_to(REPO)}:{c.lineno}" for p, c in calls if not uses_service_profile(c)]
    assert not wrong, f"plan_setpoint clients without qos_profile=qos.SERVICE: {wrong}"

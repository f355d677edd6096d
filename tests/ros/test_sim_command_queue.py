"""sim_node's command queue parameters (``command_queue_depth``, ``command_transaction``): a queue
whose transaction is not a whole number of milliseconds is refused at start, naming both
parameters (hsa_core.sim.command_queue runs on the world's 1 ms grid)."""

from __future__ import annotations

import pytest

from hsa_common.launcher import find_executable
from tests.ros.conftest import start_process

pytestmark = pytest.mark.ros


def test_a_queue_without_whole_milliseconds_exits_2_naming_the_parameters(tmp_path) -> None:
    args = [find_executable("hsa_sim_node", "sim_node"), "--ros-args"]
    for parameter in (
        "command_queue_depth:=10",
        "command_transaction:=0.0155",
        f"port:={tmp_path / 'ttyDXL'}",
    ):
        args += ["-p", parameter]
    proc = start_process(args)
    output, _ = proc.communicate(timeout=60.0)
    assert proc.returncode == 2, output
    assert "'command_queue_depth', 'command_transaction'" in output, output
    assert "whole number of ms" in output and len(output.strip().splitlines()) == 1, output

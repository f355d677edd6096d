"""The ROS-side CLIs (hsa_launch, hsa_analyze, bag_player, run_sim_experiment.py) refuse bad arguments up front: one
line on stderr, exit status 2, nothing started."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hsa_common import rosenv
from hsa_common.launcher import find_executable

REPO = Path(__file__).parents[2]
LAUNCH = REPO / "launch_scripts"
ANALYZE = find_executable("hsa_bag", "hsa_analyze")
PLAYER = find_executable("hsa_bag", "bag_player")


@pytest.mark.parametrize(("cmd", "message"), [
    (["-m", "hsa_common.launcher", str(LAUNCH / "sim.launch.yaml"), "controller:=pdi"], "is not one of"),
    (["-m", "hsa_common.launcher", str(LAUNCH / "sim.launch.yaml"), "trajectory:=ellipse"], "is not one of"),
    (["-m", "hsa_common.launcher", str(LAUNCH / "sim.launch.yaml"), "--sigterm-timeout", "-1"], "must be a finite"),
    (["-m", "hsa_common.launcher", str(LAUNCH / "sim.launch.yaml"), "record"], "name:=value"),
    ([ANALYZE, "/nonexistent/bag"], "does not exist"),
    ([ANALYZE, str(REPO), "--duration", "-1"], "must be a finite number >= 0"),
    ([PLAYER, "/nonexistent/bag"], "no such bag"),
    ([PLAYER, str(REPO), "--rate", "0"], "must be a finite number > 0"),
    ([str(LAUNCH / "run_sim_experiment.py"), "--controller", "pdi"], "invalid choice: 'pdi'"),
    ([str(LAUNCH / "run_sim_experiment.py"), "--setpoint-rate", "-1"], "must be a finite number >= 0"),
    ([str(LAUNCH / "run_sim_experiment.py"), "--gains", "no_such_gains.yaml"], "no such file: no_such_gains.yaml"),
    ([str(LAUNCH / "run_sim_experiment.py"), "--gains", str(LAUNCH / "sim.launch.yaml")],
     "is not a ROS parameter file"),
])
def test_bad_arguments_are_refused_in_one_line(tmp_path: Path, cmd: list[str], message: str) -> None:
    """Each refusal is the only line on stderr and the exit status is 2 (argparse's usage block is not printed)."""
    done = subprocess.run(cmd if cmd[0] in (ANALYZE, PLAYER) else [sys.executable, *cmd], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          env=rosenv.ros_environment())
    assert done.returncode == 2, done.stderr[-2000:]
    assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr[-2000:]
    assert "Traceback" not in done.stdout + done.stderr
    assert not (tmp_path / "out").exists()

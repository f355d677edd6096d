"""The ROS-side CLIs (hsa_launch, hsa_analyze, bag_player, run_sim_experiment.py) refuse bad
arguments up front: one line on stderr, exit status 2, nothing started. A user's ROS_DOMAIN_ID is
run on or refused, never replaced."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from hsa_common import rosenv
from hsa_common.launcher import find_executable

REPO = Path(__file__).parents[2]
LAUNCH = REPO / "launch_scripts"
ANALYZE = find_executable("hsa_bag", "hsa_analyze")
PLAYER = find_executable("hsa_bag", "bag_player")


@pytest.mark.parametrize(
    ("cmd", "message"),
    [
        (
            ["-m", "hsa_common.launcher", str(LAUNCH / "sim.launch.yaml"), "controller:=pdi"],
            "is not one of",
        ),
        (
            ["-m", "hsa_common.launcher", str(LAUNCH / "sim.launch.yaml"), "trajectory:=ellipse"],
            "is not one of",
        ),
        (
            [
                "-m",
                "hsa_common.launcher",
                str(LAUNCH / "sim.launch.yaml"),
                "--sigterm-timeout",
                "-1",
            ],
            "must be a finite",
        ),
        (["-m", "hsa_common.launcher", str(LAUNCH / "sim.launch.yaml"), "record"], "name:=value"),
        ([ANALYZE, "/nonexistent/bag"], "does not exist"),
        ([ANALYZE, str(REPO), "--duration", "-1"], "must be a finite number >= 0"),
        ([PLAYER, "/nonexistent/bag"], "no such bag"),
        ([PLAYER, str(REPO), "--rate", "0"], "must be a finite number > 0"),
        ([str(LAUNCH / "run_sim_experiment.py"), "--controller", "pdi"], "invalid choice: 'pdi'"),
        (
            [str(LAUNCH / "run_sim_experiment.py"), "--setpoint-rate", "-1"],
            "must be a finite number >= 0",
        ),
        (
            [str(LAUNCH / "run_sim_experiment.py"), "--gains", "no_such_gains.yaml"],
            "no such file: no_such_gains.yaml",
        ),
        (
            [str(LAUNCH / "run_sim_experiment.py"), "--gains", str(LAUNCH / "sim.launch.yaml")],
            "is not a ROS parameter file",
        ),
        (
            [str(LAUNCH / "run_sim_experiment.py"), "--profile", "nope"],
            "unknown run profile 'nope'; known: lab",
        ),
        (
            [str(LAUNCH / "run_sim_experiment.py"), "--run", "nope"],
            "unknown run of the paper 'nope'; known: 2023",
        ),
        (
            [str(LAUNCH / "run_sim_experiment.py"), "--run", "20230925_102428"],
            "contour of tud_flame.jpeg (tud-phi/hsa-planar-control, assets/; not packaged): no "
            "--image-dir given",
        ),
        (
            [str(LAUNCH / "run_sim_experiment.py"), "--run", "20230925_093236", "--profile", "lab"],
            "--run replays a run with its own profile",
        ),
        (
            [str(LAUNCH / "run_sim_experiment.py"), "--sigma-a-eq", "1,0"],
            "must be A or A,B with finite numbers > 0",
        ),
        (
            [str(LAUNCH / "run_sim_experiment.py"), "--payload", "-0.1"],
            "must be a finite number >= 0",
        ),
        ([ANALYZE, "nope_run", "--against", "20230925_093236"], "not a real run of the paper"),
    ],
)
def test_bad_arguments_are_refused_in_one_line(
    tmp_path: Path, cmd: list[str], message: str
) -> None:
    """Each refusal is the only line on stderr and the exit status is 2 (argparse's usage block is
    not printed)."""
    done = subprocess.run(
        cmd if cmd[0] in (ANALYZE, PLAYER) else [sys.executable, *cmd],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
        env=rosenv.ros_environment(),
    )
    assert done.returncode == 2, done.stderr[-2000:]
    assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr[-2000:]
    assert "Traceback" not in done.stdout + done.stderr
    assert not (tmp_path / "out").exists()


def user_env(domain: str, tmp_path: Path) -> dict[str, str]:
    """A user's shell that set ROS_DOMAIN_ID (no hsa-ros parent); domain locks in a private
    TMPDIR."""
    env = {k: v for k, v in os.environ.items() if k not in ("HSA_ROS_ENV", "ROS_DOMAIN_ID")}
    return {**env, "ROS_DOMAIN_ID": domain, "TMPDIR": str(tmp_path)}


@pytest.mark.parametrize(
    "cmd",
    [
        ["-m", "hsa_common.launcher", str(LAUNCH / "sim.launch.yaml"), "--print"],
        [str(LAUNCH / "run_sim_experiment.py"), "--out", "out"],
    ],
)
def test_a_bad_user_domain_is_refused_in_one_line(tmp_path: Path, cmd: list[str]) -> None:
    """ROS_DOMAIN_ID=150 (Linux's ephemeral ports) is refused before anything starts, not replaced
    by a reserved one."""
    done = subprocess.run(
        [sys.executable, *cmd],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
        env=user_env("150", tmp_path),
    )
    assert done.returncode == 2 and done.stdout == "", done.stdout[-2000:]
    assert done.stderr.count("\n") == 1 and "ROS_DOMAIN_ID='150'" in done.stderr, done.stderr[
        -2000:
    ]
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "out").exists()


def test_hsa_launch_runs_its_nodes_on_the_user_domain(tmp_path: Path) -> None:
    """With ROS_DOMAIN_ID=7 the launched process's rclpy context is on domain 7."""
    probe = (
        "import rclpy; rclpy.init(); print('domain', rclpy.get_default_context().get_domain_id(), "
        "flush=True)"
    )
    graph = tmp_path / "probe.launch.yaml"
    graph.write_text(
        yaml.safe_dump(
            {
                "launch": [
                    {
                        "executable": {
                            "cmd": shlex.join([sys.executable, "-c", probe]),
                            "name": "probe",
                            "output": "screen",
                        }
                    }
                ]
            }
        )
    )
    done = subprocess.run(
        [sys.executable, "-m", "hsa_common.launcher", str(graph)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
        env=user_env("7", tmp_path),
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "domain 7\n" in done.stdout, done.stdout[-2000:]

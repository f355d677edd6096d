"""hsa_experiment refuses bad arguments before running anything: one line on stderr, exit status 2;
run.sh and test.sh run from any directory."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).parents[2]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--controller", "pdi"], "unknown law(s) ['pdi']"),
        (
            ["--controller", "psatid,pdi"],
            "unknown law(s) ['pdi']",  # it ran psatid in full, then crashed
        ),
        (["--rate", "33"], "must divide 1000 Hz"),
        (["--rate", "0"], "must divide 1000 Hz"),
        (["--trajectory", "no_such_image.png"], "must be steps, star, circle or an image file"),
        (["--contour-k", "0"], "must be an integer >= 1"),
        (["--duration", "-5"], "must be a finite number > 0"),
        (["--profile", "sep2024"], "unknown run profile 'sep2024'; known: lab, sep2023, oct2023"),
        (
            ["--run", "20230925_000000"],
            "unknown run of the paper '20230925_000000'; known: 20230925_092200, ",
        ),
    ],
)
def test_bad_arguments_are_refused_up_front_in_one_line(
    tmp_path, args: list[str], message: str
) -> None:
    """No traceback, no run: the refusal names the argument, and nothing is written."""
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "hsa_core.sim.experiment", *args, "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr[-2000:]
    assert done.stdout == "" and done.stderr.count("\n") == 1, done.stderr[-2000:]
    assert done.stderr.startswith("hsa_experiment: error: argument") and message in done.stderr, (
        done.stderr
    )
    assert not out.exists()


@pytest.mark.parametrize(
    ("script", "usage"),
    [("run.sh", "usage: run_sim_experiment.py"), ("test.sh", "usage: python -m pytest")],
)
def test_scripts_run_from_another_directory(tmp_path: Path, script: str, usage: str) -> None:
    """run.sh and test.sh work whatever the caller's directory (the bootstrap's globs are the
    checkout's; it is a no-op here, where test.sh has just run it)."""
    done = subprocess.run(
        [str(REPO / script), "--help"], capture_output=True, text=True, timeout=300, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith(usage), done.stdout[:2000]

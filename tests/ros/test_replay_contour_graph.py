"""./run.sh --run on a contour run of the paper (launch_scripts/run_sim_experiment.py: the lockstep
graph, then the analysis of its bag) equals hsa_experiment --run tick by tick. The authors' images
are not packaged: a dark disc stands in for mit_csail.png, so the CSAIL run of 2023-09-25
(P-satI-D, September profile, k = 8, r_max 0.017 m, 8 Hz) plays a few points."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from hsa_core.runs.catalogue import replayable
from hsa_core.runs.runlog import RunLog
from hsa_core.sim.experiment import replay_config, run_experiment
from tests.ros.conftest import start_process, stop_process

pytestmark = [pytest.mark.ros, pytest.mark.slow]

SCRIPT = Path(__file__).parents[2] / "launch_scripts" / "run_sim_experiment.py"
BAG = "20230925_113825"  # FPU CSAIL contour, P-satI-D (experiments.md §7)


def test_a_contour_replay_in_the_graph_equals_the_offline_replay(tmp_path: Path) -> None:
    images = tmp_path / "assets"
    images.mkdir()
    disc = np.full((100, 100, 3), 255, np.uint8)
    cv2.circle(disc, (50, 50), 25, (0, 0, 0), -1)
    cv2.imwrite(str(images / "mit_csail.png"), disc)
    config = replay_config(replayable(BAG, image_dir=images))
    assert 10 <= len(config.reference.t) <= 30  # a short run: a few contour points
    offline = run_experiment(config)

    out = tmp_path / "out"
    proc = start_process(
        [sys.executable, str(SCRIPT), "--run", BAG, "--image-dir", str(images), "--out", str(out)]
    )
    try:
        output, _ = proc.communicate(timeout=900)
    finally:
        stop_process(proc)
    assert proc.returncode == 0, output[-5000:]
    graph = RunLog.load_npz(out / "run.npz")
    n = len(offline.log)
    assert len(graph) >= n > 0
    np.testing.assert_allclose(graph.t[:n], offline.log.t, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(graph.phi_sat[:n], offline.log.phi_sat, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(graph.chiee[:n], offline.log.chiee, rtol=0.0, atol=1e-12)
    rmse = f"{offline.metrics.rmse * 1e3:.2f}"
    assert any(line.split()[:2] == ["fpu_psatid_ros", rmse] for line in output.splitlines()), (
        f"the graph's metrics table does not show the offline RMSE {rmse} mm:\n{output[-3000:]}"
    )

"""A paper run's schedule as ./run.sh --run gives it to the real setpoint_sequencer
(hsa_core.sim.run_conditions.run_schedule): the node plays the offline replay's reference."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
import yaml

from hsa_common.launcher import find_executable
from hsa_core.runs.catalogue import replayable
from hsa_core.sim.experiment import replay_config
from hsa_core.sim.run_conditions import run_schedule
from tests.ros.conftest import start_process, stop_process, wait_for_line

pytestmark = pytest.mark.ros


@pytest.mark.parametrize(
    "bag", ["20231019_083240", "20230925_142209"]
)  # bat L contour; payload steps
def test_the_sequencer_plays_a_paper_run_as_the_offline_replay(tmp_path, bag: str) -> None:
    image = np.full((400, 400, 3), 255, np.uint8)  # a stand-in for bat.png: a dark disc
    cv2.circle(image, (200, 200), 150, (0, 0, 0), -1)
    cv2.imwrite(str(tmp_path / "bat.png"), image)
    run = replayable(bag, image_dir=tmp_path)
    offline = replay_config(run).reference
    schedule = run_schedule(run)
    rate = schedule.pop("rate")  # a launch argument of sim.launch.yaml, given after the file
    params = tmp_path / "sequencer.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": schedule}}))
    exe = find_executable("hsa_planner_node", "setpoint_sequencer")
    proc = start_process(
        [exe, "--ros-args", "-r", "__ns:=/replay", "--params-file", str(params)]
        + ["-p", f"rate:={rate!r}", "-p", f"material:={run.conditions.material}"]
    )
    try:
        lines = wait_for_line(proc, "points every")
    finally:
        stop_process(proc)
    found = re.search(r"(\d+) points every ([0-9.e+-]+) s", lines[-1])
    assert found is not None, lines[-1]
    assert int(found.group(1)) == len(offline.t)
    assert float(found.group(2)) == pytest.approx(offline.duration / len(offline.t))

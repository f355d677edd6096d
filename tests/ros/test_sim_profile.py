"""The lockstep graph under a run profile: launch_scripts/sim.launch.yaml with the September 2023
conditions (36 ms control period, integrators at the nominal 25 ms, the 16-tick stand-in velocity
estimator at the controller, the command queue in sim_node's world,
hsa_core.sim.run_conditions.graph_arguments) and the calibrated FPU
world (``disturbance:=calibrated``, hsa_core.sim.disturbance.calibrated_world) equals the offline
experiment under the same profile and world tick by tick, on a short FPU P-satI-D step schedule, as
tests/ros/test_sim_in_the_loop.py checks for the lab default."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from hsa_bag.bagrun import runlog_from_bag
from hsa_core.runs.profiles import load_profile
from hsa_core.sim.disturbance import calibrated_world
from hsa_core.sim.experiment import profile_config, run_experiment
from hsa_core.sim.run_conditions import graph_arguments
from hsa_core.task.trajectories import step_reference
from tests.ros.conftest import (
    GRAPH_STOP,
    LAUNCHER,
    start_process,
    stop_process,
    write_step_sequence,
)

pytestmark = [pytest.mark.ros, pytest.mark.slow]

GRAPH = Path(__file__).parents[2] / "launch_scripts" / "sim.launch.yaml"
STEPS = 2
STEP_PERIOD = 2.0  # s per setpoint
PROFILE = load_profile("sep2023")


def test_the_graph_in_the_september_profile_and_calibrated_world_equals_the_offline_experiment(
    tmp_path: Path,
) -> None:
    bag = tmp_path / "bag"
    config = tmp_path / "sequencer.yaml"
    write_step_sequence(config, STEPS)
    conditions = [f"{k}:={v}" for k, v in graph_arguments(PROFILE).items()]
    proc = start_process(
        [
            *LAUNCHER,
            str(GRAPH),
            *GRAPH_STOP,
            "material:=fpu",
            "controller:=psatid",
            "disturbance:=calibrated",
            *conditions,
            f"setpoint_rate:={1.0 / STEP_PERIOD}",
            f"bag_dir:={bag}",
            f"sequencer_config:={config}",
            "clock:=lockstep",
        ]
    )
    try:
        output, _ = proc.communicate(timeout=900)
    finally:
        stop_process(proc)
    assert proc.returncode == 0, output[-5000:]
    reference = step_reference(np.asarray(step_reference("fpu").p_des[:STEPS]), period=STEP_PERIOD)
    world = calibrated_world("fpu")
    september = profile_config(PROFILE, "fpu", "psatid", reference=reference, disturbance=world)
    offline = run_experiment(september)
    log = runlog_from_bag(bag).trimmed(STEPS * STEP_PERIOD)
    # ticks every 36 ms in 4 s, the first one after 16 tick samples
    assert len(log) == len(offline.log) == 112
    np.testing.assert_allclose(log.t, offline.log.t, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(log.phi_sat, offline.log.phi_sat, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(log.chiee, offline.log.chiee, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(log.e_int, offline.log.e_int, rtol=0.0, atol=1e-9)
    # the command queue reached sim_node's world: without it the run is another
    direct = run_experiment(dataclasses.replace(september, command_queue=(0, 0.0)))
    assert np.max(np.abs(direct.log.phi_sat - log.phi_sat)) > 1e-6

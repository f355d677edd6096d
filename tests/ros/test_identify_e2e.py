"""Identification end to end in the simulated graph: bags → hsa_identify → parameter YAML → planner
and controller.

The campaign tests/ros/data/identify_sim/campaign.yaml is recorded with
launch_scripts/identify.launch.yaml (sim:=true, clock:=lockstep, disturbance:=declared): three short
staircases (elongation, rod1, rod2) played by excitation_player through the real driver, payloads
hung by hsa_sim_node's `payload_schedule` while the motors hold. The three graphs run at the same
time, each in its own ROS domain; lockstep makes every bag a deterministic function of its arguments
whatever the load. hsa_identify fits the bags; the written YAML is run in the offline closed-loop
step experiment (hsa_core.sim.experiment.run_experiment) against the simulator's plant, next to the
packaged set.

Expected values come from the declarations, not from the code under test: the simulator's plant is
the packaged FPU set with the declared mismatch of hsa_core.sim.disturbance (S_b_hat, S_sh_hat,
S_a_hat, S_b_sh x 1.05, C_eps x 0.97, C_S_* unchanged). RTOL bounds the identification error of this
campaign under the declared mocap noise (0.1 mm, 0.1 mm, 1 mrad at 200 Hz): the same holds (levels,
payloads, 1 s windows at the plant's static equilibria) identified with 60 noise seeds gave at most
C_eps 0.06 %, S_a_hat 2.5 %, C_S_a 18 %, S_b_hat 4.4 %, S_sh_hat 2.4 %, S_b_sh 1.9 %, C_S_b 5.3 %,
C_S_sh 48 % (tests/ros/data/identify_sim/rtol_study.py; shear is the least observable,
docs/identification.md §4); the bounds are about 1.5x that.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import subprocess
from contextlib import ExitStack
from pathlib import Path
from typing import TextIO

import numpy as np
import pytest
import yaml

from hsa_bag.bagio import Bag
from hsa_common import rosenv
from hsa_core.model.params import HsaParams, load_params
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.sim.experiment import ExperimentConfig, ExperimentResult, run_experiment
from hsa_core.sysid import identification
from hsa_core.task.trajectories import step_reference
from hsa_identification.cli import identify_main
from tests.ros.conftest import GRAPH_STOP, LAUNCHER, stop_process

pytestmark = [pytest.mark.ros, pytest.mark.slow]

GRAPH = Path(__file__).parents[2] / "launch_scripts" / "identify.launch.yaml"
CAMPAIGN = Path(__file__).parent / "data" / "identify_sim" / "campaign.yaml"
HOLD = 6.0  # s per staircase level (two payload holds of 3 s)
FINAL_HOLD = 0.5  # s of phi = 0 after the staircase (too short to count as a hold)
EXCITATION = {
    "elong": ("elongation", 2),
    "bend_rod1": ("rod1", 3),
    "bend_rod2": ("rod2", 3),  # mode, n_levels
}
TOPICS = "[/hsa/ee_pose, /hsa/phi_present, /hsa/phi_cmd, /hsa/excitation_info]"
MOCAP_PERIOD = 0.005  # s
RTOL = {
    "C_eps": 1e-3,
    "S_a_hat": 0.04,
    "C_S_a": 0.25,
    "S_b_hat": 0.06,
    "S_sh_hat": 0.04,
    "S_b_sh": 0.03,
    "C_S_b": 0.08,
    "C_S_sh": 0.7,
}
RESOLVED = ("C_eps", "S_a_hat", "S_sh_hat", "S_b_sh")
"""Mismatched constants whose bound is below the mismatch (3 %, 5 %): they must come out nearer the
plant."""
STEPS, STEP_PERIOD = 4, 2.0  # closed-loop check: the first 4 FPU steps, 2 s each
RMSE_FACTOR = 1.1
"""The identified set may track at most 10 % worse than the packaged one. On this run the plant's
own constants (a perfect identification) track within 1.5 % of the packaged set (the step transients
dominate the RMSE), while a broken set (C_eps halved) is 29 % worse."""


def _graph(
    bag: Path, log: TextIO, mode: str, n_levels: int, payload: list[list[float]]
) -> subprocess.Popen:
    """Start one identification graph in a ROS domain of its own (the launcher reserves it), output
    to `log`."""
    flat = ", ".join(repr(float(v)) for pair in payload for v in pair)
    env = rosenv.ros_environment()
    for key in (
        "HSA_ROS_ENV",
        "ROS_DOMAIN_ID",
    ):  # not the test session's domain: three graphs run at once
        env.pop(key)
    return subprocess.Popen(
        [
            *LAUNCHER,
            str(GRAPH),
            *GRAPH_STOP,
            "sim:=true",
            "clock:=lockstep",
            "disturbance:=declared",
            "kind:=staircase",
            f"mode:={mode}",
            f"n_levels:={n_levels}",
            f"hold:={HOLD}",
            "start_delay:=0.0",
            f"final_hold:={FINAL_HOLD}",
            f"payload_schedule:=[{flat}]",
            f"bag_dir:={bag}",
            f"topics:={TOPICS}",
        ],
        env=env,
        start_new_session=True,
        stdout=log,
        stderr=subprocess.STDOUT,
        text=True,
    )


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """Record the campaign's three bags next to a copy of the campaign file; return that copy."""
    work = tmp_path_factory.mktemp("identify_e2e")
    shutil.copy(CAMPAIGN, work / "campaign.yaml")
    records = yaml.safe_load(CAMPAIGN.read_text())["records"]
    procs = {}
    with ExitStack() as logs:
        try:
            for record in records:
                name = Path(record["path"]).name
                mode, n_levels = EXCITATION[name]
                log = logs.enter_context((work / f"{name}.log").open("w"))
                procs[name] = _graph(work / record["path"], log, mode, n_levels, record["payload"])
            for proc in procs.values():
                proc.wait(timeout=600)
        finally:
            for proc in procs.values():
                stop_process(proc)
    for name, proc in procs.items():
        output = (work / f"{name}.log").read_text()
        assert proc.returncode == 0, output[-5000:]
        assert "excitation_player exited with 0" in output, output[-5000:]
    return work / "campaign.yaml"


@pytest.fixture(scope="module")
def identified(campaign) -> Path:
    """Run hsa_identify on the campaign; return its output directory."""
    out = campaign.parent / "identification"
    assert identify_main([str(campaign), "--out", str(out)]) == 0
    return out


def _stamps(bag: Path, topic: str) -> np.ndarray:
    """header.stamp of every message on `topic` [s]."""
    with Bag(bag) as reader:
        store, msgtype = reader.typestore(topic), reader.topic(topic).msgtype
        stamps = [
            store.deserialize_cdr(raw, msgtype).header.stamp
            for _, _, raw in reader.messages([topic])
        ]
    return np.array([s.sec + s.nanosec * 1e-9 for s in stamps])


def _commands(bag: Path) -> tuple[np.ndarray, np.ndarray]:
    """(stamp [s], phi) of every excitation command on phi_cmd."""
    with Bag(bag) as reader:
        store, msgtype = reader.typestore("/hsa/phi_cmd"), reader.topic("/hsa/phi_cmd").msgtype
        msgs = [
            store.deserialize_cdr(raw, msgtype) for _, _, raw in reader.messages(["/hsa/phi_cmd"])
        ]
    return (
        np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in msgs]),
        np.array([np.asarray(m.phi, dtype=float) for m in msgs]),
    )


def test_the_records_start_at_simulated_time_zero_and_levels_change_on_schedule(campaign) -> None:
    """The campaign's payload times are record times; they are simulated times because the first
    recorded pose is the sample of instant 0 and the player steps its levels at multiples of `hold`
    of simulated time."""
    phi_max = float(np.min(np.asarray(load_params("fpu").phi_max)))
    for record in yaml.safe_load(campaign.read_text())["records"]:
        bag = campaign.parent / record["path"]
        _, n_levels = EXCITATION[Path(record["path"]).name]
        poses = _stamps(bag, "/hsa/ee_pose")
        assert poses[0] == 0.0
        np.testing.assert_allclose(np.diff(poses), MOCAP_PERIOD, rtol=0, atol=1e-9)  # none missing
        t, phi = _commands(bag)
        level = np.max(phi, axis=1)
        changes = t[1:][np.abs(np.diff(level)) > 1e-9]
        # up the stairs, back to 0
        expected = [k * HOLD for k in range(1, n_levels + 1)] + [(n_levels + 1) * HOLD]
        np.testing.assert_allclose(changes, expected, rtol=0, atol=1e-9)
        np.testing.assert_allclose(
            level[(t >= n_levels * HOLD) & (t < (n_levels + 1) * HOLD)], phi_max, rtol=1e-12
        )


def test_every_hold_of_the_campaign_is_a_settled_sample(identified) -> None:
    """Two payload holds per level: 3 levels (elongation) + 2 x 4 levels (bending) = 22 samples."""
    with np.load(identified / "samples.npz") as samples:
        assert len(samples["payload"]) == 2 * (3 + 4 + 4)
        np.testing.assert_array_equal(np.bincount(samples["record"]), [6, 8, 8])
        assert sorted(set(samples["payload"].tolist())) == [0.0, 0.2, 0.4]


def test_the_identified_constants_are_the_simulated_plants(identified) -> None:
    """Per physical rod, within RTOL of the plant (packaged set with the declared mismatch); the
    constants whose bound is below the mismatch come out nearer the plant than the packaged set;
    everything else is the packaged set's."""
    nominal = load_params("fpu")
    params = load_params(identified / "identified.yaml")
    plant = identification.per_rod_constants(DisturbanceModel().plant_params(nominal))
    packaged = identification.per_rod_constants(nominal)
    found = identification.per_rod_constants(params)
    for key, value in plant.items():
        assert found[key] == pytest.approx(value, rel=RTOL[key]), (key, found[key] / value - 1.0)
    for key in RESOLVED:
        assert abs(found[key] - plant[key]) < abs(found[key] - packaged[key]), key
    unchanged = [
        f.name for f in dataclasses.fields(HsaParams) if f.name not in identification.ELASTIC_KEYS
    ]
    for name in unchanged:
        np.testing.assert_array_equal(
            np.asarray(getattr(params, name)), np.asarray(getattr(nominal, name)), name
        )


@dataclasses.dataclass(frozen=True)
class _SimulatorPlant(DisturbanceModel):
    """The declared world, with the simulator's plant whatever model the controller is
    given."""

    plant: HsaParams | None = None

    def plant_params(self, model: HsaParams) -> HsaParams:
        """The simulator's plant (not the controller's model with the mismatch applied)."""
        return self.plant


def _steps(params_file: str, plant: HsaParams) -> ExperimentResult:
    """P-satI-D step experiment with planner and controller on `params_file`, plant = the
    simulator's."""
    reference = step_reference(np.asarray(step_reference("fpu").p_des[:STEPS]), period=STEP_PERIOD)
    return run_experiment(
        ExperimentConfig(
            params_file, "psatid", reference=reference, disturbance=_SimulatorPlant(plant=plant)
        )
    )


def test_planner_and_controller_on_the_identified_set_track_the_simulated_plant(identified) -> None:
    plant = DisturbanceModel().plant_params(load_params("fpu"))
    nominal = _steps("fpu", plant)
    ident = _steps(str(identified / "identified.yaml"), plant)
    assert not ident.plan_failures
    rmse, rmse_nominal = ident.metrics.rmse, nominal.metrics.rmse
    print(
        f"\nstep RMSE, P-satI-D, {STEPS} FPU steps of {STEP_PERIOD:g} s, simulated plant: "
        f"identified set {rmse * 1e3:.3f} mm, packaged set {rmse_nominal * 1e3:.3f} mm; true e_ss "
        f"{ident.true_steady_state_error() * 1e3:.3f} / "
        f"{nominal.true_steady_state_error() * 1e3:.3f} mm"
    )
    assert math.isfinite(rmse)
    assert rmse <= RMSE_FACTOR * rmse_nominal

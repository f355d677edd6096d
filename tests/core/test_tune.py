"""hsa_tune: the objective ranks gain sets as intended, the gains file has the controller's
parameter names."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from hsa_core.apps import robustness, tune
from hsa_core.controller.control import CollocatedGains, ControllerKind, PidGains, default_gains
from hsa_core.model.params import load_params
from hsa_core.sim import closed_loop
from hsa_core.sim.disturbance import DisturbanceModel, calibrated_world
from hsa_core.sim.experiment import ExperimentConfig
from hsa_core.task.trajectories import TimedReference, step_reference


def test_the_gains_file_uses_the_controller_parameter_names() -> None:
    doc = yaml.safe_load(
        tune.gains_yaml(
            ControllerKind.PSATID, CollocatedGains(kp=0.2, ki=0.01, kd=0.005, gamma=100.0), "x"
        )
    )
    assert doc == {"/**": {"ros__parameters": {"kp": 0.2, "ki": 0.01, "kd": 0.005, "gamma": 100.0}}}
    doc = yaml.safe_load(
        tune.gains_yaml(ControllerKind.PID, PidGains(kp=5.0, ki=50.0, kd=0.1), "x")
    )
    assert doc == {"/**": {"ros__parameters": {"kp_pid": 5.0, "ki_pid": 50.0, "kd_pid": 0.1}}}


def test_log_gains_map_back_to_round_values() -> None:
    gains = tune.to_gains(
        ControllerKind.PSATID, default_gains("psatid"), np.log10([0.3, 0.05, 0.02])
    )
    assert (gains.kp, gains.ki, gains.kd, gains.gamma) == (0.3, 0.05, 0.02, 100.0)


def test_an_oscillating_gain_set_scores_worse_than_a_calm_one() -> None:
    ref = step_reference("fpu")
    keep = ref.t < 20.0
    reference = TimedReference(ref.t[keep], ref.p_des[keep], ref.name, 20.0)
    disturbance = DisturbanceModel()
    spec, inputs, constants = closed_loop.prepare(
        ExperimentConfig("fpu", "psatid", reference=reference, disturbance=disturbance)
    )
    plants = robustness.perturbed_plants(
        disturbance.plant_params(load_params("fpu")), 1, 0.0, seed=0
    )
    noises = np.asarray(inputs.noise)[None]
    # mostly the setpoint's feedforward phi_ss
    calm = CollocatedGains(kp=0.01, ki=0.01, kd=0.02, gamma=100.0)
    wild = CollocatedGains(kp=3.0, ki=0.05, kd=0.02, gamma=100.0)  # ten times the paper's kp
    # padded to 3, the extra run dropped
    calm_score, wild_score = tune.evaluate_population(
        ControllerKind.PSATID, [calm, wild], spec, inputs, constants, plants, noises, batch=3
    )
    assert calm_score.rmse_mm.shape == wild_score.rmse_mm.shape == (1,)
    assert calm_score.terms["bad"] == 0.0 and wild_score.terms["bad"] == 1.0
    assert wild_score.objective > calm_score.objective + tune.WEIGHTS["bad"]
    assert wild_score.terms["effort_rad"] > 3 * calm_score.terms["effort_rad"]


def test_bad_arguments_are_refused_in_one_line(capsys) -> None:
    for argv, text in (
        (["--law", "pdi"], "invalid choice"),
        (["--duration", "10"], "at least two steps"),
        (["--population", "1"], "at least 2"),
    ):
        with pytest.raises(SystemExit) as exc:
            tune.main(argv)
        assert exc.value.code == 2 and text in capsys.readouterr().err


def test_the_named_world_and_profile_reach_the_tuning_loop(monkeypatch, capsys) -> None:
    """--disturbance calibrated --profile sep2023 set the world and the set-up of the loop the
    tuner prepares (the tuning itself is cut short there); a bad world is a one-line refusal."""
    seen = []

    class Prepared(Exception):
        pass

    def stop(config):  # noqa: ANN001, ANN202 - records the config, ends the run
        seen.append(config)
        raise Prepared

    monkeypatch.setattr(closed_loop, "prepare", stop)
    with pytest.raises(Prepared):
        tune.main(["--disturbance", "calibrated", "--profile", "sep2023", "--seed", "2"])
    (config,) = seen
    assert config.disturbance == calibrated_world("fpu", seed=2)
    assert config.profile == "sep2023" and config.rate == pytest.approx(1e3 / 36)
    assert config.command_queue == (10, pytest.approx(0.016))
    with pytest.raises(SystemExit) as exc:
        tune.main(["--disturbance", "wood"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "unknown world 'wood'" in err and len(err.splitlines()) == 1

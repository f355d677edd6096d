"""Run profiles (hsa_core.runs.profiles) and replaying a paper run with its own conditions
(hsa_core.sim.experiment): the profiles hold the spec's values, ``lab`` is today's default exactly,
a replay takes the run's logbook conditions and real step instants, and the September profile's
rate, integrator step and estimator reach the run."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest

from hsa_core.controller.control import CollocatedGains, PidGains
from hsa_core.runs import profiles, reference
from hsa_core.runs.profiles import VelocityEstimator
from hsa_core.sim import experiment
from hsa_core.sim.disturbance import calibrated_world
from hsa_core.sim.experiment import ExperimentConfig, profile_config, replay_config, run_experiment
from hsa_core.sim.run_conditions import graph_arguments
from hsa_core.task.trajectories import TimedReference, step_reference


def _one_step(material: str = "fpu", seconds: float = 2.0) -> TimedReference:
    ref = step_reference(material)
    return TimedReference(ref.t[:1], ref.p_des[:1], "one_step", seconds)


def test_the_profiles_hold_the_spec_s_conditions() -> None:
    """experiments.md §1, §5 and planning_and_control.md §3.1, §6.4, §8 (values written here from
    the spec)."""
    assert profiles.profile_names() == ("lab", "sep2023", "oct2023")
    sep, oct_, lab = (profiles.load_profile(n) for n in ("sep2023", "oct2023", "lab"))
    assert (sep.control_period_ms, sep.integrator_dt, sep.bus_baud) == (36, 0.025, 2_000_000)
    assert sep.velocity_estimator is VelocityEstimator.SMOOTHING_SPLINE_16
    assert (oct_.control_period_ms, oct_.integrator_dt, oct_.bus_baud) == (25, 0.025, 4_000_000)
    assert oct_.velocity_estimator is VelocityEstimator.SAVITZKY_GOLAY_20
    assert (lab.control_period_ms, lab.integrator_dt, lab.rate) == (25, None, 40.0)
    assert all(p.sigma_a_eq is None and p.payload == 0.0 for p in (sep, oct_, lab))
    # reference_ros_graph.md §3, §5, §6 item 2; ecosystem.md §3.1 (derivation in profiles.yaml)
    assert (sep.command_latency_ms, oct_.command_latency_ms, lab.command_latency_ms) == (0, 6, 0)
    # September: per-motor keep-last-10 topics, one driver thread, 16 ms transactions (p&c §7-8)
    assert (sep.command_queue_depth, sep.command_transaction_ms) == (10, 16)
    assert oct_.command_queue_depth == lab.command_queue_depth == 0
    with pytest.raises(
        ValueError, match=r"^unknown run profile 'sep2024'; known: lab, sep2023, oct2023$"
    ):
        profiles.load_profile("sep2024")


def test_the_lab_profile_is_today_s_default_bit_for_bit() -> None:
    lab = profiles.load_profile("lab")
    assert profile_config(lab, "fpu", "psatid") == ExperimentConfig("fpu", "psatid")
    reference_ = _one_step()
    with_profile = run_experiment(profile_config(lab, "fpu", "psatid", reference=reference_))
    without = run_experiment(ExperimentConfig("fpu", "psatid", reference=reference_))
    for name in ("t", "chiee", "chiee_des", "q", "phi_sat", "e_int", "phi_meas"):
        np.testing.assert_array_equal(
            getattr(with_profile.log, name), getattr(without.log, name), err_msg=name
        )
    np.testing.assert_array_equal(with_profile.true_chiee, without.true_chiee)


def test_the_cli_without_a_profile_runs_the_lab_default() -> None:
    """hsa_experiment --material fpu --controller psatid,pid builds exactly the configs it built
    before profiles, in the world its --disturbance default names."""
    args = argparse.Namespace(
        run=None,
        profile=None,
        material="fpu",
        controller=["psatid", "pid"],
        trajectory="steps",
        sigma_a_eq=None,
        payload=None,
        duration=None,
        kd=None,
        rate=None,
        disturbance="calibrated",
        seed=0,
    )
    dist = calibrated_world("fpu", seed=0)
    configs = experiment._configs(args)
    assert [dataclasses.replace(c, reference=None) for c in configs] == [
        ExperimentConfig("fpu", law, False, None, 40.0, dist) for law in ("psatid", "pid")
    ]
    # the material's step list (a TimedReference holds arrays: compared field by field)
    for config in configs:
        np.testing.assert_array_equal(config.reference.t, step_reference("fpu").t)
        np.testing.assert_array_equal(config.reference.p_des, step_reference("fpu").p_des)
        assert config.reference.duration == step_reference("fpu").duration


def test_a_replay_takes_the_run_s_conditions_and_real_step_instants() -> None:
    """Expected values from shared/realdata/README.md (gains, σ_a,eq, 2 Mbps in September) and the
    step instants it quotes for 093236 (9.87, 19.55, 29.95 ... 99.54 s: the first 10 ms sample after
    the move within one sample)."""
    config = replay_config(reference.load_run("20230925_093236"))
    assert (config.material, config.controller, config.profile) == ("fpu", "psatid", "sep2023")
    assert config.gains == CollocatedGains(0.3, 0.05, 0.02, 100.0)
    assert config.sigma_a_eq == pytest.approx((1.00711, 1.00711), abs=5e-6)
    assert (1e3 / config.rate, config.integrator_dt) == (pytest.approx(36.0), 0.025)
    assert config.velocity_estimator is VelocityEstimator.SMOOTHING_SPLINE_16
    t = config.reference.t
    assert len(t) == 11 and t[0] == 0.0
    assert t[1:4] == pytest.approx([9.87, 19.55, 29.95], abs=0.0101) and t[-1] == pytest.approx(
        99.54, abs=0.0101
    )
    # the 09-25 list, experiments.md §2
    np.testing.assert_allclose(config.reference.p_des, step_reference("fpu").p_des)
    pid_run = reference.load_run("20230925_092200")
    pid = replay_config(pid_run)
    # the logbook's σ_a,eq leaves the fifth setpoint (y = 114.6 mm) without a plan (docs): the
    # plant keeps it, the controller's model (only the planner's, for PID) gets the nominal 1.0
    assert pid.gains == PidGains(10.0, 110.0, 0.25) and pid.plant_sigma_a_eq == pytest.approx(
        (1.02776, 1.02776), abs=5e-6
    )
    assert pid.sigma_a_eq == (1.0, 1.0)
    assert pid.rest_strain_shift == pytest.approx((0.02776, 0.02776), abs=5e-6)
    # its own 38 ms ticks (runs.yaml), in the offline replay and in the graph's launch arguments
    assert 1e3 / pid.rate == pytest.approx(38.0) and pid.integrator_dt == 0.025
    graph = graph_arguments(pid_run.conditions.profile, run=pid_run)
    assert 1e3 / float(graph["rate"]) == pytest.approx(38.0)
    epu = replay_config(reference.load_run("20231019_143126"), payload=0.2)
    assert (epu.material, epu.profile, epu.rate, epu.integrator_dt) == (
        "epu",
        "oct2023",
        40.0,
        0.025,
    )
    assert epu.sigma_a_eq == pytest.approx((1.05441, 1.04468), abs=5e-6) and epu.payload == 0.2
    assert epu.velocity_estimator is VelocityEstimator.SAVITZKY_GOLAY_20


def test_the_september_profile_reaches_the_run() -> None:
    """36 ms ticks; no command before the stand-in estimator has 16 tick samples; the integrator
    steps 0.025 s."""
    config = dataclasses.replace(
        replay_config(reference.load_run("20230925_093236")), reference=_one_step()
    )
    result = run_experiment(config)
    t_ns = np.array([tick.t_ns for tick in result.ticks])
    assert np.all(np.diff(t_ns) == 36_000_000) and t_ns[0] == 36_000_000
    first = result.ticks[
        next(i for i, tick in enumerate(result.ticks) if np.isfinite(tick.phi).all())
    ]
    # the 16th tick feeds the 16th sample; the first state goes to the next
    assert first.t_ns >= 16 * 36_000_000
    # P-satI-D: e_int += tanh(γ e)·dt, |tanh| ≤ 1, γ = 100 saturates it on a step: per-tick change
    # up to dt, not 36 ms
    step = np.abs(np.diff(np.array([tick.e_int for tick in result.ticks]), axis=0)).max()
    assert 0.02 < step <= 0.025 + 1e-12


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"payload": -0.1}, "payload must be a finite mass >= 0 kg"),
        ({"integrator_dt": 0.0}, "integrator_dt must be > 0 s"),
        ({"sigma_a_eq": (1.0, -1.0)}, "sigma_a_eq must be two values > 0"),
        ({"command_latency": -0.001}, "command_latency must be >= 0 s"),
    ],
)
def test_invalid_conditions_are_refused(kw: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ExperimentConfig("fpu", "psatid", **kw)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--sigma-a-eq", "1.0,-1"],
            "argument --sigma-a-eq: must be A or A,B with finite numbers > 0, got 1.0,-1",
        ),
        (["--sigma-a-eq", "1,2,3"], "argument --sigma-a-eq: must be A or A,B"),
        (["--payload", "-1"], "argument --payload: must be a finite number >= 0"),
        (
            ["--run", "20230925_093236", "--material", "epu", "--rate", "40"],
            "argument --run: the run sets its own --material, --rate; leave them out",
        ),
    ],
)
def test_bad_profile_arguments_are_one_line_refusals(capsys, argv: list[str], message: str) -> None:
    with pytest.raises(SystemExit) as done:
        experiment.main([*argv, "--quiet"])
    err = capsys.readouterr().err
    assert done.value.code == 2 and err.count("\n") == 1 and message in err, err


def test_a_payload_is_the_plant_s_from_rest() -> None:
    """The plant hangs at rest with the payload from t = 0 (lower than without); the controller's
    model keeps m_pl."""
    config = ExperimentConfig("fpu", "psatid", reference=_one_step(seconds=0.5))
    loaded = dataclasses.replace(config, payload=0.2)
    assert float(loaded.model().m_pl) == 0.0
    sag = run_experiment(loaded).true_chiee[0, 1] - run_experiment(config).true_chiee[0, 1]
    assert abs(sag) > 1e-4, sag  # 0.29 mm for 0.2 kg on the default FPU plant


def test_the_batched_loop_takes_the_profile_s_conditions() -> None:
    """Period, integrator step, estimator and payload reach the batched loop (its equality with
    run_experiment on a
    September replay: tests/core/test_closed_loop.py)."""
    from hsa_core.sim import closed_loop

    october = dataclasses.replace(
        replay_config(reference.load_run("20231019_143126")), reference=_one_step("epu")
    )
    spec, _, _ = closed_loop.prepare(october)
    assert (spec.period_ms, spec.dt) == (25, 0.025)
    assert spec.velocity_estimator is VelocityEstimator.SAVITZKY_GOLAY_20
    september = replay_config(reference.load_run("20230925_093236"), payload=0.2)
    spec, inputs, _ = closed_loop.prepare(september)
    assert (spec.period_ms, spec.dt) == (36, 0.025)
    assert spec.velocity_estimator is VelocityEstimator.SMOOTHING_SPLINE_16
    assert float(inputs.plant.m_pl) == 0.2

"""The world's calibration (hsa_core.apps.calibrate): the fitter recovers a known world; the CLI's
outputs and refusals."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from hsa_core.analysis import sim_to_real
from hsa_core.apps import calibrate
from hsa_core.runs.profiles import VelocityEstimator
from hsa_core.sim import closed_loop
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.sim.experiment import ExperimentConfig
from hsa_core.task.trajectories import TimedReference, step_reference


def synthetic_run(truth: DisturbanceModel) -> calibrate.PreparedRun:
    """A 3 s FPU P-satI-D run (in the declared world) with one step at 0.5 s whose 'robot' is the
    simulation in the world ``truth``."""
    ref = step_reference("fpu")
    reference = TimedReference(np.array([0.0, 0.5]), ref.p_des[1:3], "two_points", 3.0)
    config = ExperimentConfig("fpu", "psatid", reference=reference, disturbance=DisturbanceModel())
    spec, inputs, constants = closed_loop.prepare(config)
    run = calibrate.PreparedRun("synthetic", config, spec, inputs, constants, None, "", (1,), 2.0)
    robot = calibrate.simulate(run, [truth])[0]
    run.robot = sim_to_real.StepRun(robot.t, robot.p, robot.p_des, robot.end)
    return run


def test_the_search_recovers_a_known_actuation_latency_and_a_flat_parameter_is_reported() -> None:
    # longer than the 25 ms period: two goals in flight
    truth = DisturbanceModel(actuation_latency=0.047)
    run = synthetic_run(truth)
    fit = calibrate.search(
        [run], ("actuation_latency",), DisturbanceModel(), population=8, generations=4
    )
    assert fit.best["actuation_latency"] == pytest.approx(0.047, abs=1.5e-3)
    assert fit.objective < 1e-4 and fit.evaluations == 32
    values, d = calibrate.scan(
        [run], "actuation_latency", DisturbanceModel(actuation_latency=0.047), points=8
    )
    # the population's batch size: no second compilation
    assert len(values) == 8 and 0.047 in values
    found = calibrate.identification(values, d, fit.best["actuation_latency"])
    assert found["identified"] and found["interval"][0] <= 0.047 <= found["interval"][1]
    # the truth reproduces the robot
    assert d[np.argmin(np.abs(values - 0.047))] == pytest.approx(0.0, abs=1e-12)
    flat = calibrate.identification(
        np.array([1.0, 2.0, 3.0]), np.array([1e-3, 1e-3 + 1e-6, 1e-3]), 2.0
    )
    assert not flat["identified"]


def test_the_world_kept_is_refitted_without_the_parameters_it_does_not_keep() -> None:
    """The truth's time constant (0) is the lower bound of its range, so it is not identified and
    the world keeps the base's; the latency, searched together with a time constant the world does
    not keep, is searched again alone on the base world and lands on the truth."""
    run = synthetic_run(DisturbanceModel(actuation_latency=0.047))
    fit = calibrate.fit_world(
        [run],
        ("actuation_latency", "servo_time_constant"),
        DisturbanceModel(),
        population=8,
        generations=4,
        scan_points=7,
    )
    assert fit.identification["servo_time_constant"]["status"] == "not identified (at bound)"
    assert fit.identified == ("actuation_latency",) and fit.refit is not None
    assert fit.kept == {
        "actuation_latency": fit.refit.best["actuation_latency"],
        "servo_time_constant": 0.0,
    }
    assert fit.kept["actuation_latency"] == pytest.approx(0.047, abs=1.5e-3)
    kept = calibrate.deviations(run, [DisturbanceModel(**fit.kept)])[0]
    assert kept == pytest.approx(fit.refit.objective, abs=1e-12) and kept < 1e-4
    # the latency's interval is the second scan's, around the world kept
    assert fit.identification["actuation_latency"]["best"] == fit.kept["actuation_latency"]


def test_a_scan_whose_interval_reaches_a_bound_is_not_identified() -> None:
    """D falling to the scan's lower bound, or to the last value where the run is finite, moves by
    far more than the tolerance, yet the data put the minimum outside the range: not identified."""
    values = np.array([0.0, 0.025, 0.05, 0.1, 0.15])
    falling = calibrate.identification(values, np.array([1.0, 1.2, 1.5, 2.0, 2.5]) * 1e-3, 0.0)
    assert not falling["identified"] and falling["status"] == "not identified (at bound)"
    assert falling["interval"] == [0.0, 0.0]
    unstable = np.array([1.9, 1.8, 1.6, math.inf, math.inf]) * 1e-3  # an integration limit
    at_edge = calibrate.identification(values, unstable, 0.05)
    assert at_edge["status"] == "not identified (at bound)" and at_edge["interval"] == [0.05, 0.05]
    inner = calibrate.identification(values, np.array([2.0, 1.5, 1.0, 1.5, 2.0]) * 1e-3, 0.05)
    assert inner["identified"] and inner["status"] == "identified"


def test_a_scan_holds_both_bounds_and_the_world_s_value() -> None:
    run = synthetic_run(DisturbanceModel())
    values, d = calibrate.scan(
        [run], "servo_time_constant", DisturbanceModel(servo_time_constant=0.149), points=8
    )
    np.testing.assert_allclose(values, [0.0, 0.025, 0.05, 0.075, 0.1, 0.125, 0.149, 0.15])
    assert d.shape == (8,) and d[0] == pytest.approx(0.0, abs=1e-12)  # the truth: the default


def test_a_diverged_plant_is_no_candidate_even_when_the_estimator_hides_it() -> None:
    """Damping far beyond the RK4 step's stability limit: under the September estimator (which
    refuses non-finite states and keeps its last finite one) the measured pose stays finite, yet
    the candidate's positions are NaN, so its D is inf."""
    ref = step_reference("fpu")
    reference = TimedReference(np.array([0.0]), ref.p_des[1:2], "one_point", 1.0)
    config = ExperimentConfig(
        "fpu",
        "psatid",
        reference=reference,
        rate=1000.0 / 36,
        velocity_estimator=VelocityEstimator.SMOOTHING_SPLINE_16,
        disturbance=DisturbanceModel(),
    )
    spec, inputs, constants = closed_loop.prepare(config)
    run = calibrate.PreparedRun("x", config, spec, inputs, constants, None, "", (1,), 0.3)
    worlds = [DisturbanceModel(), DisturbanceModel(damping_scale=20.0)]
    calm, diverged = calibrate.simulate(run, worlds)
    assert np.isnan(diverged.p).all() and np.isfinite(calm.p).all()


def test_parameters_map_to_their_grid_and_bounds() -> None:
    lat = calibrate.PARAMETERS["actuation_latency"]
    np.testing.assert_allclose(lat.value(np.array([-1.0, 0.5, 2.0])), [0.0, 0.125, 0.25])
    damping = calibrate.PARAMETERS["damping_scale"]
    assert damping.value(np.array([0.5]))[0] == pytest.approx(2.0)
    assert damping.unit(2.0) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="whole ms up to 250 ms"):
        calibrate.candidate_inputs(
            synthetic_run(DisturbanceModel()), [DisturbanceModel(actuation_latency=0.0305)]
        )


def test_a_run_s_command_latency_adds_to_every_candidate_s_latency() -> None:
    """A run whose controller side adds a command latency (a profile's): each candidate world's
    actuation latency is the world's plus the run's, as in the offline experiment (the declared
    world's own latency: 2 ms)."""
    ref = step_reference("fpu")
    reference = TimedReference(np.array([0.0]), ref.p_des[1:2], "one_point", 1.0)
    config = ExperimentConfig(
        "fpu", "psatid", reference=reference, command_latency=0.011, disturbance=DisturbanceModel()
    )
    spec, inputs, constants = closed_loop.prepare(config)
    run = calibrate.PreparedRun("x", config, spec, inputs, constants, None, "", (1,), 1.0)
    assert int(inputs.actuation_latency_ms) == 13
    worlds = [DisturbanceModel(actuation_latency=a) for a in (0.0, 0.002, 0.25)]
    np.testing.assert_array_equal(
        calibrate.candidate_inputs(run, worlds).actuation_latency_ms, [11, 13, 261]
    )


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--fit", "friction"], "unknown or repeated parameter(s)"),
        (["--runs", "nope"], "unknown reference run(s)"),
        (["--population", "1"], "--population: must be >= 2"),
        (["--duration", "5"], "hold no whole step"),
        (["--static", "--material", "wood"], "argument --material: invalid choice: 'wood'"),
        (["--static"], "argument --material: required with --static"),
        (["--material", "fpu"], "argument --material: only with --static"),
        (["--write-world"], "argument --write-world: only with --static"),
        (["--static", "--material", "fpu", "--population", "4"], "--population: not with --static"),
        (
            ["--static", "--material", "fpu", "--noise-seeds", "4"],
            "--noise-seeds: not with --static",
        ),
        (["--held-out-seeds", "-1"], "--held-out-seeds: must be an integer >= 0"),
    ],
)
def test_bad_arguments_are_one_line_refusals(argv: list[str], message: str, capsys) -> None:
    with pytest.raises(SystemExit) as done:
        calibrate.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert done.value.code == 2 and len(err) == 1 and message in err[0], err


def test_the_cli_writes_world_report_and_figure_on_a_tiny_budget(tmp_path) -> None:
    out = tmp_path / "cal"
    code = calibrate.main(
        [
            "--runs",
            "20231019_143126",
            "--duration",
            "20",
            "--population",
            "2",
            "--generations",
            "1",
            "--scan-points",
            "2",
            "--fit",
            "servo_time_constant",
            "--held-out-seeds",
            "0",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    assert report["held_out_noise"] is None
    row = report["per_run"]["20231019_143126"]
    assert len(row["calibrated"]["D_per_step_mm"]) == 1 and math.isfinite(row["calibrated"]["D_mm"])
    assert set(report["identification"]) == {"servo_time_constant"}
    world = yaml.safe_load((out / "world.yaml").read_text())
    assert set(world["parameters"]["servo_time_constant"]) >= {
        "value",
        "fitted",
        "identified",
        "status",
        "interval",
    }
    assert world["held_out_noise_D_mm"] is None
    assert world["conditions"]["20231019_143126"]["profile"] == "oct2023"
    assert world["conditions"]["20231019_143126"]["command_latency_ms"] == 6
    assert world["conditions"]["20231019_143126"]["control_period_ms"] == 25
    assert (out / "20231019_143126.png").stat().st_size > 10_000


def test_noise_realizations_of_a_queued_run_are_pooled(tmp_path) -> None:
    """Under the September command queue a run depends on its mocap noise realization (whether a
    goal changes at a tick decides the driver's backlog): ``--noise-seeds 2`` scores each candidate
    on two realizations, and the run's D is the root mean square of the two."""
    out = tmp_path / "cal"
    argv = ["--runs", "20230925_093236", "--duration", "20", "--population", "2"]
    argv += ["--generations", "1", "--scan-points", "2", "--fit", "servo_time_constant"]
    argv += ["--noise-seeds", "2", "--held-out-seeds", "1"]
    assert calibrate.main([*argv, "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["noise_seeds"] == 2
    row = report["per_run"]["20230925_093236"]["base"]
    one, two = row["D_per_noise_seed_mm"]
    assert one != two  # the queue makes the realizations differ
    assert row["D_mm"] == pytest.approx(math.sqrt((one**2 + two**2) / 2), abs=1e-3)
    # the world is then scored on a realization the fit did not see: seed 2, another run again
    held = report["held_out_noise"]
    assert held["seeds"] == [2]
    (third,) = held["per_run"]["20230925_093236"]["base"]["D_per_noise_seed_mm"]
    assert third not in (one, two)
    world = yaml.safe_load((out / "world.yaml").read_text())
    assert world["noise_seeds"] == 2
    assert world["held_out_noise_D_mm"]["seeds"] == [2]
    assert world["held_out_noise_D_mm"]["pooled"] == held["D_mm"]["calibrated"]

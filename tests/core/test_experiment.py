"""Offline experiment pieces: the disturbance model, the per-tick RunLog and its exports, figures,
and a short closed-loop run whose outcome is checked against the reference it was asked to track."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hsa_core.analysis import plotting
from hsa_core.model.params import load_params
from hsa_core.runs.runlog import RunLog
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.sim.experiment import ExperimentConfig, main, run_experiment
from hsa_core.task.trajectories import step_reference


def make_log(n: int = 50) -> RunLog:
    """A RunLog with recognisable contents (row k holds k in every column)."""
    k = np.arange(n, dtype=float)
    col = lambda w: np.repeat(k[:, None], w, axis=1)  # noqa: E731
    return RunLog(
        t=k * 0.025,
        chiee=col(3),
        chiee_des=col(3) + 1,
        q=col(3),
        q_des=col(3),
        varphi=col(3),
        varphi_des=col(3),
        phi_ss=col(2),
        phi_unsat=col(2),
        phi_sat=col(2),
        e_int=col(2),
        saturated=k % 2 == 0,
        meta={"material": "fpu", "controller": "psatid"},
    )


def test_runlog_rejects_inconsistent_rows() -> None:
    log = make_log()
    with pytest.raises(ValueError, match="RunLog.q has shape"):
        RunLog(**{**vars(log), "q": log.q[:-1]})
    with pytest.raises(ValueError, match="RunLog.phi_sat"):
        RunLog(**{**vars(log), "phi_sat": log.q})


def test_runlog_npz_and_csv_round_trip(tmp_path) -> None:
    log = make_log()
    back = RunLog.load_npz(log.save_npz(tmp_path / "log.npz"))
    for name in ("t", "chiee", "phi_sat", "saturated"):
        np.testing.assert_array_equal(getattr(back, name), getattr(log, name))
    assert back.meta == log.meta
    rows = np.loadtxt(log.save_csv(tmp_path / "log.csv"), delimiter=",", skiprows=1)
    header = (tmp_path / "log.csv").read_text().splitlines()[0].split(",")
    assert len(header) == 1 + 3 * 6 + 2 * 4 + 1 and header[:4] == [
        "t [s]",
        "chiee_x [m]",
        "chiee_y [m]",
        "chiee_theta [rad]",
    ]
    np.testing.assert_array_equal(rows[:, header.index("chiee_des_y [m]")], np.arange(50) + 1)
    assert rows.shape == (50, len(header))


def test_trimmed_keeps_the_window() -> None:
    log = make_log().trimmed(0.5)
    assert len(log) == 20 and log.t[-1] < 0.5


def test_figures_are_written(tmp_path) -> None:
    paths = plotting.all_figures(make_log(), tmp_path, prefix="x_", phi_max=3.49, contour=True)
    stems = [
        "x_end_effector",
        "x_path",
        "x_actuation",
        "x_configuration",
        "x_collocated",  # contour: no steps
    ]
    assert [p.name for p in paths] == [f"{s}.{fmt}" for s in stems for fmt in ("pdf", "png")]
    assert all(p.read_bytes()[:4] == (b"%PDF" if p.suffix == ".pdf" else b"\x89PNG") for p in paths)


def test_disturbance_none_is_the_model_and_default_is_the_declared_mismatch() -> None:
    model = load_params("fpu")
    same = DisturbanceModel.none().plant_params(model)
    for key in ("S_a_hat", "S_sh_hat", "C_eps", "sigma_a_eq"):
        np.testing.assert_array_equal(
            np.asarray(getattr(same, key)), np.asarray(getattr(model, key))
        )
    plant = DisturbanceModel().plant_params(model)
    # virtual rod = 2 x physical (model.md §5.3)
    np.testing.assert_allclose(plant.S_a_hat, 1.05 * 2 * 5.66472469)
    np.testing.assert_allclose(plant.C_eps, 0.97 * 0.00984819)
    np.testing.assert_allclose(plant.sigma_a_eq, [1.005, 1.005])
    sheared = DisturbanceModel.shear_mismatch().plant_params(model)
    np.testing.assert_allclose(sheared.S_sh_hat, 0.5 * 1.05 * 2 * 5.91462074e-1)
    with pytest.raises(ValueError, match="pose_noise_std"):
        DisturbanceModel(pose_noise_std=(-1.0, 0.0, 0.0))


def test_noise_is_seeded() -> None:
    dist = DisturbanceModel()
    # MX-28 no-load speed at 12 V
    assert dist.servo_max_speed == pytest.approx(55 * 2 * math.pi / 60)
    noise = np.array([dist.measure(dist.rng(), np.zeros(3)) for _ in range(3)])
    assert np.all(noise == noise[0])  # same seed, same sample


def test_in_world_replaces_fields_of_the_base_world_only() -> None:
    config = ExperimentConfig("fpu", "psatid", command_latency=0.03)
    seeded = config.in_world(seed=5)
    assert seeded.disturbance.seed == 5
    assert config.base_world().seed != 5
    assert seeded.disturbance.actuation_latency == config.base_world().actuation_latency
    # the run's own conditions still apply on top of the new base world
    assert seeded.world().actuation_latency == config.world().actuation_latency
    with pytest.raises(TypeError):
        config.in_world(no_such_field=1.0)


@pytest.fixture(scope="module")
def epu_run():
    """Two 5 s EPU steps with P-satI-D and the paper's gains under the default disturbance."""
    ref = step_reference("epu", period=5.0)
    short = type(ref)(ref.t[:2], ref.p_des[:2], "epu_2steps", 10.0)
    return run_experiment(ExperimentConfig("epu", "psatid", reference=short))


def test_closed_loop_tracks_the_steps(epu_run) -> None:
    log, m = epu_run.log, epu_run.metrics
    assert abs(len(log) - 400) <= 1 and m.control_rate == pytest.approx(40.0)  # 10 s at 40 Hz
    # EPU step 2 (experiments.md §2)
    np.testing.assert_allclose(log.chiee_des[-1, :2], [-0.01137064, 0.13488599])
    step = m.steps[1]
    assert step.response_time < 1.5  # the paper's EPU P-satI-D responds in ~0.5 s
    # noise-free plant position at the end of the step: within 0.5 mm of the target
    assert np.linalg.norm(epu_run.true_chiee[-1, :2] - log.chiee_des[-1, :2]) < 0.5e-3
    assert np.all(log.phi_sat >= 0.0) and np.all(log.phi_sat <= 4.7123890 + 1e-12)
    assert not epu_run.plan_failures


def test_cli_writes_table_logs_and_figures(tmp_path, capsys) -> None:
    assert (
        main(
            [
                "--material",
                "epu",
                "--controller",
                "psatid",
                "--duration",
                "2",
                "--quiet",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "epu_psatid" in out and "RMSE [mm]" in out
    run_dir = tmp_path / "epu_psatid"
    assert {p.name for p in run_dir.iterdir()} >= {
        "log.npz",
        "log.csv",
        "end_effector.png",
        "actuation.png",
    }
    assert len(RunLog.load_npz(run_dir / "log.npz")) == 80


def test_a_diverging_plant_ends_the_run_with_one_line() -> None:
    """A world beyond the plant's integration limit (here 30 times the damping) fails at once,
    naming the cause, instead of running on without a command."""
    reference = step_reference(np.array([[0.0, 0.12]]), period=2.0)
    config = ExperimentConfig(
        "fpu", "pid", reference=reference, disturbance=DisturbanceModel(damping_scale=30.0)
    )
    with pytest.raises(RuntimeError, match=r"^fpu_pid: the simulated plant diverged by t = "):
        run_experiment(config)


def test_a_run_whose_controller_never_tracks_ends() -> None:
    """No setpoint can be planned (far outside the workspace): the run ends after the last one plus
    the duration and says so, instead of waiting forever for a first command."""
    reference = step_reference(np.array([[0.5, 0.5]]), period=1.0)
    with pytest.raises(RuntimeError, match="the controller never ran"):
        run_experiment(ExperimentConfig("fpu", "psatid", reference=reference))

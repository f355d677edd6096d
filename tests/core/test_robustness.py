"""hsa_robustness: plant perturbations, the unstable / limit-cycle classification, and the CLI end
to end."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from hsa_core.apps import batch_metrics, robustness
from hsa_core.controller.control import ControllerKind
from hsa_core.model.actuation import MotorMap
from hsa_core.model.params import load_params
from hsa_core.sim import closed_loop
from hsa_core.sim.disturbance import DisturbanceModel, calibrated_world
from hsa_core.sim.experiment import ExperimentConfig
from hsa_core.task.trajectories import TimedReference, step_reference

PERIOD_MS = 25
N = 800  # 20 s at 40 Hz: two steps of 10 s


def spec() -> closed_loop.LoopSpec:
    return closed_loop.LoopSpec(
        ControllerKind.PSATID, False, None, PERIOD_MS, 6, N + 5, 5, N, MotorMap(phi_max=1.0), 0.025
    )


def log_of(true_xy: np.ndarray) -> closed_loop.TickLog:
    """A TickLog whose law ran from tick 5 on, reference (0, 0.12) then (0.005, 0.128) m, plant at
    ``true_xy``."""
    n = N + 5
    desired = np.zeros((n, 3))
    desired[:, 1] = 0.12
    desired[5 + N // 2 :, :2] = (0.005, 0.128)
    true = np.zeros((n, 3))
    true[5:, :2] = true_xy
    ran = np.arange(n) >= 5
    return closed_loop.TickLog(ran, true, desired, np.zeros((n, 2)), np.zeros(n, bool), true)


def reference_xy() -> np.ndarray:
    xy = np.tile([0.0, 0.12], (N, 1))
    xy[N // 2 :] = (0.005, 0.128)
    return xy


def test_a_settled_run_is_neither_unstable_nor_cycling() -> None:
    assert robustness.classify(spec(), log_of(reference_xy() + 1e-4)) == (False, False)


def test_an_oscillation_in_the_last_two_seconds_is_a_limit_cycle() -> None:
    xy = reference_xy()
    t = np.arange(N) * PERIOD_MS * 1e-3
    # 3 mm peak to peak, only at the very end
    xy[:, 0] += 1.5e-3 * np.sin(2 * np.pi * 11.0 * t) * (t > 18.0)
    assert robustness.classify(spec(), log_of(xy)) == (False, True)
    # 1.8 mm: below the threshold
    xy[:, 0] = reference_xy()[:, 0] + 0.9e-3 * np.sin(2 * np.pi * 11.0 * t)
    assert robustness.classify(spec(), log_of(xy)) == (False, False)


def test_a_large_or_non_finite_error_is_unstable() -> None:
    xy = reference_xy()
    xy[N // 2 - 80 : N // 2] += 0.05  # 70 mm off over the last 2 s of the first step
    assert robustness.classify(spec(), log_of(xy)) == (True, False)
    xy = reference_xy()
    xy[-1, 0] = np.nan
    assert robustness.classify(spec(), log_of(xy)) == (True, False)


def test_plants_are_perturbed_within_the_range_and_reproducible() -> None:
    base = load_params("fpu")
    a, b = (
        robustness.perturbed_plants(base, 8, 0.1, seed=3),
        robustness.perturbed_plants(base, 8, 0.1, seed=3),
    )
    assert np.array_equal(a.factors, b.factors) and np.array_equal(a.seeds, b.seeds)
    assert np.all((a.factors >= 0.9) & (a.factors <= 1.1)) and np.ptp(a.factors) > 0.05
    np.testing.assert_allclose(
        np.asarray(a.params.S_a_hat)[2], np.asarray(base.S_a_hat) * a.factors[2, 0]
    )
    np.testing.assert_allclose(
        np.asarray(a.params.C_eps)[5], np.asarray(base.C_eps) * a.factors[5, 1]
    )
    np.testing.assert_allclose(
        np.asarray(a.params.sigma_a_eq)[7], np.asarray(base.sigma_a_eq) * a.factors[7, 2]
    )


def test_bad_arguments_are_refused_in_one_line(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        robustness.main(["--laws", "psatid,pdi"])
    assert exc.value.code == 2 and "unknown law(s) ['pdi']" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        robustness.main(["--range", "1.5"])
    assert exc.value.code == 2 and "--range must be in [0, 1)" in capsys.readouterr().err


def test_the_study_writes_its_table_and_figures(tmp_path, capsys) -> None:
    assert (
        robustness.main(
            [
                "--n",
                "2",
                "--laws",
                "psatid",
                "--duration",
                "10",
                "--batch",
                "2",
                "--disturbance",
                "calibrated",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    doc = json.loads((tmp_path / "robustness.json").read_text())
    assert (doc["world"], doc["profile"]) == ("calibrated", "lab")
    summary = doc["summary"]["psatid"]
    assert summary["runs"] == 2 and 0.5 < summary["rmse_mm"]["median"] < 20.0
    rows = (tmp_path / "robustness.csv").read_text().splitlines()
    assert rows[0].startswith("law,plant,stiffness") and len(rows) == 3
    for stem in ("rmse_by_law", "worst_psatid"):
        assert (tmp_path / f"{stem}.pdf").stat().st_size > 0 and (
            tmp_path / f"{stem}.png"
        ).stat().st_size > 0
    assert "psatid" in capsys.readouterr().out


def test_bad_gains_arguments_are_refused_in_one_line(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        robustness.main(["--gains", "pdi=x.yaml"])
    assert exc.value.code == 2 and "expected LAW=FILE" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        robustness.main(["--gains", f"psatid={tmp_path / 'missing.yaml'}"])
    err = capsys.readouterr().err
    assert (
        exc.value.code == 2
        and "missing.yaml: not a gains file for psatid" in err
        and len(err.splitlines()) == 1
    )
    gains = tmp_path / "g.yaml"
    gains.write_text("/**:\n  ros__parameters: {kp: 0.1, ki: 0.01, kd: 0.01, gamma: 100.0}\n")
    with pytest.raises(SystemExit) as exc:
        robustness.main(["--laws", "pid", "--gains", f"psatid={gains}"])
    assert (
        exc.value.code == 2
        and "--gains for ['psatid'], which --laws does not run" in capsys.readouterr().err
    )


def test_gains_from_a_file_replace_the_papers(tmp_path) -> None:
    """Feedforward only (gains ~0) tracks differently from the paper's gains on the same plants; the
    JSON says which."""
    gains = tmp_path / "ff.yaml"
    gains.write_text(
        "/**:\n  ros__parameters: {kp: 1.0e-9, ki: 1.0e-9, kd: 1.0e-9, gamma: 100.0}\n"
    )
    common = ["--n", "1", "--laws", "psatid", "--duration", "10", "--batch", "1"]
    assert robustness.main([*common, "--out", str(tmp_path / "paper")]) == 0
    assert (
        robustness.main([*common, "--gains", f"psatid={gains}", "--out", str(tmp_path / "ff")]) == 0
    )
    paper, ff = (
        json.loads((tmp_path / d / "robustness.json").read_text()) for d in ("paper", "ff")
    )
    assert (
        paper["gains"] == {}
        and ff["gains"]["psatid"]["kp"] == 1e-9
        and ff["gains"]["psatid"]["file"] == str(gains)
    )
    assert ff["summary"]["psatid"]["rmse_mm"]["median"] != pytest.approx(
        paper["summary"]["psatid"]["rmse_mm"]["median"], rel=1e-3
    )


def test_the_bound_settles_each_reachable_plant_on_its_setpoints(tmp_path) -> None:
    """Perfect-model feedforward: no steady-state error beyond the servo's tick (a tick of twist
    moves the EE by well under 0.3 mm), no oscillation; plants that cannot reach every setpoint are
    left out, not run."""
    assert (
        robustness.main(
            [
                "--n",
                "4",
                "--laws",
                "bound",
                "--duration",
                "20",
                "--batch",
                "4",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    summary = json.loads((tmp_path / "robustness.json").read_text())["summary"]["bound"]
    rows = [r for r in (tmp_path / "robustness.csv").read_text().splitlines()[1:]]
    assert 1 <= summary["runs"] == len(rows) <= 4
    assert summary["e_ss_mm"]["max"] < 0.3 and summary["limit_cycle_fraction"] == 0.0
    assert summary["unstable_fraction"] == 0.0


def test_the_batched_noise_is_each_seeds_noise() -> None:
    config = ExperimentConfig("fpu", "psatid")
    spec = closed_loop.LoopSpec(
        ControllerKind.PSATID, False, None, 25, 6, 400, 5, 395, MotorMap(phi_max=1.0), 0.025
    )
    seeds = np.array([0, 7, 2**31 - 2])
    batch = closed_loop.noise_batch(config.base_world(), spec, seeds)
    for i, seed in enumerate(seeds):
        assert np.array_equal(
            batch[i], closed_loop.noise(config.base_world(), spec, seed=int(seed))
        )


def test_a_short_last_batch_runs_in_the_compiled_shape(monkeypatch) -> None:
    """3 plants at batch 2: the last batch (1 plant) is padded to 2, so the loop and the metrics see
    one batch shape and the loop is compiled once; the padded run is dropped. Plant 2 is plant 0
    again: the same record."""
    shapes = []
    rollout, metrics = closed_loop.batch_rollout, batch_metrics.evaluate

    def spy_rollout(spec, inputs, *rest):  # noqa: ANN001, ANN202 - the real function, its batch sizes recorded
        shapes.append(("loop", np.shape(inputs.noise)[0]))
        return rollout(spec, inputs, *rest)

    def spy_metrics(spec, logs):  # noqa: ANN001, ANN202
        shapes.append(("metrics", logs.ran.shape[0]))
        return metrics(spec, logs)

    monkeypatch.setattr(closed_loop, "batch_rollout", spy_rollout)
    monkeypatch.setattr(batch_metrics, "evaluate", spy_metrics)
    disturbance = DisturbanceModel()
    two = robustness.perturbed_plants(disturbance.plant_params(load_params("fpu")), 2, 0.1, seed=5)
    pick = np.array([0, 1, 0])
    plants = robustness.Plants(
        two.factors[pick],
        jax.tree_util.tree_map(lambda a: np.asarray(a)[pick], two.params),
        two.seeds[pick],
    )
    ref = step_reference("fpu")
    reference = TimedReference(ref.t[:1], ref.p_des[:1], ref.name, 10.0)
    spec = closed_loop.prepare(
        ExperimentConfig("fpu", "psatid", reference=reference, disturbance=disturbance)
    )[0]
    compiled = closed_loop._batched(
        spec, closed_loop.LoopInputs(0, None, 0, None), closed_loop.LoopConstants(None, None, None)
    )
    before = compiled._cache_size()
    records, worst = robustness.run_law("psatid", "fpu", plants, disturbance, 2, reference)
    assert sorted(set(shapes)) == [("loop", 2), ("metrics", 2)] and len(shapes) == 4
    assert compiled._cache_size() - before <= 1
    assert [r["plant"] for r in records] == [0, 1, 2]
    for key in ("rmse_mm", "e_ss_mm", "t_r_s", "overshoot_mm", "saturated"):
        assert records[2][key] == pytest.approx(records[0][key], rel=1e-12, nan_ok=True)
    assert np.isfinite(records[0]["rmse_mm"]) and records[0]["rmse_mm"] != records[1]["rmse_mm"]
    assert worst.record is records[int(np.argmax([r["rmse_mm"] for r in records]))]


def test_a_bad_world_or_profile_is_refused_in_one_line(capsys) -> None:
    for argv, text in (
        (["--disturbance", "wood"], "argument --disturbance: unknown world 'wood'"),
        (["--disturbance", "default"], "argument --disturbance: 'default' is now 'declared'"),
        (["--profile", "sep2024"], "unknown run profile 'sep2024'"),
    ):
        with pytest.raises(SystemExit) as exc:
            robustness.main(argv)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and text in err and len(err.splitlines()) == 1


def test_the_named_world_and_profile_reach_every_run(monkeypatch) -> None:
    """--disturbance calibrated --profile sep2023: the plants are drawn around the calibrated
    plant, and the runs are in that world under that profile (a spy records, and ends the study)."""
    seen = []

    class Ran(Exception):
        pass

    def spy(law, material, plants, disturbance, *rest):  # noqa: ANN001, ANN202 - records
        seen.append((plants, disturbance, rest[-1]))
        raise Ran

    monkeypatch.setattr(robustness, "run_law", spy)
    argv = ["--n", "2", "--laws", "psatid", "--seed", "3"]
    with pytest.raises(Ran):
        robustness.main([*argv, "--disturbance", "calibrated", "--profile", "sep2023"])
    ((plants, disturbance, profile),) = seen
    assert disturbance == calibrated_world("fpu", seed=3) and profile.name == "sep2023"
    calibrated, default = (
        robustness.perturbed_plants(world.plant_params(load_params("fpu")), 2, 0.1, seed=3)
        for world in (disturbance, DisturbanceModel(seed=3))
    )
    for name in ("sigma_a_eq", "sigma_sh_eq", "S_b_hat", "C_eps"):
        got = np.asarray(getattr(plants.params, name))
        np.testing.assert_array_equal(got, np.asarray(getattr(calibrated.params, name)))
    assert not np.array_equal(
        np.asarray(plants.params.sigma_sh_eq), np.asarray(default.params.sigma_sh_eq)
    )

"""Every run of the paper by its bag name (hsa_core.runs.catalogue): the packaged reference runs and
the runs known by their conditions only (spec experiments.md §7), replayed with those conditions
(hsa_experiment --run, run_schedule for ./run.sh --run)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from hsa_core.controller.control import CollocatedGains, ControllerKind, PidGains
from hsa_core.runs import catalogue, reference
from hsa_core.runs.catalogue import CataloguedRun
from hsa_core.sim.experiment import main, replay_config
from hsa_core.sim.run_conditions import run_schedule

# experiments.md §7, "Runs behind the figures": bag → (material, law); dates from the table's rows
SPEC_RUNS = {
    "20230925_092200": ("fpu", "pid"),
    "20230925_093236": ("fpu", "psatid"),
    "20230925_094023": ("fpu", "psatid_gc"),
    "20230925_143544": ("fpu", "pid"),
    "20230925_142209": ("fpu", "psatid"),
    "20230925_142729": ("fpu", "psatid_gc"),
    "20230925_100308": ("fpu", "pid"),
    "20230925_101931": ("fpu", "pid"),
    "20230925_113430": ("fpu", "pid"),
    "20230925_095416": ("fpu", "psatid"),
    "20230925_102428": ("fpu", "psatid"),
    "20230925_113825": ("fpu", "psatid"),
    "20230925_095851": ("fpu", "psatid_gc"),
    "20230925_102856": ("fpu", "psatid_gc"),
    "20230925_114328": ("fpu", "psatid_gc"),
    "20231017_112545": ("fpu", "psatid"),
    "20231017_113913": ("fpu", "psatid"),
    "20231017_115721": ("fpu", "psatid"),
    "20231019_072747": ("fpu", "psatid"),
    "20231019_081703": ("fpu", "psatid"),
    "20231019_082343": ("fpu", "psatid"),
    "20231019_083240": ("fpu", "psatid"),
    "20231019_084052": ("fpu", "psatid"),
    "20231019_084914": ("fpu", "psatid"),
    "20231019_132825": ("epu", "pid"),
    "20231019_143126": ("epu", "psatid"),
    "20231019_134251": ("epu", "psatid"),
    "20231019_135129": ("epu", "psatid_gc"),
}


def test_every_run_of_the_paper_is_known_with_its_material_law_and_period() -> None:
    assert set(catalogue.run_names()) == set(SPEC_RUNS)
    for bag, (material, law) in SPEC_RUNS.items():
        cond = catalogue.replayable(bag).conditions
        assert (cond.bag, cond.material, cond.law) == (bag, material, ControllerKind(law))
        assert cond.date.strftime("%Y%m%d") == bag[:8]
        # p&c §3.6; September set-up until the bus change of 2023-10-13 (experiments.md §1)
        assert cond.profile.name == ("sep2023" if bag < "20231013" else "oct2023")
        if law == "pid":
            assert cond.gains == PidGains(10.0, 110.0, 0.25)
        else:
            slow = bag.startswith("20231019_0")  # K_d 0.01: the logbook, 072747 included
            assert cond.gains == CollocatedGains(0.3, 0.05, 0.01 if slow else 0.02, 100.0)


def test_a_packaged_run_is_the_reference_run_and_the_others_have_no_traces() -> None:
    assert isinstance(catalogue.replayable("20230925_093236"), reference.ReferenceRun)
    run = catalogue.replayable("20231019_135129")
    assert isinstance(run, CataloguedRun)
    assert run.conditions.sigma_a_eq == (1.05545513, 1.05023814)  # experiments.md §7
    # the authors' logbook (data/experiments/logbook.xlsx): calibrated before the run, per rod
    assert catalogue.replayable("20231019_134251").conditions.sigma_a_eq == (1.05613547, 1.04291502)
    with pytest.raises(ValueError, match="unknown run of the paper '20230925_000000'"):
        catalogue.replayable("20230925_000000")


def test_a_payload_step_run_replays_with_its_payload_and_the_fpu_steps() -> None:
    run = catalogue.replayable("20230925_142209")
    config = replay_config(run)
    assert config.payload == pytest.approx(0.2)  # experiments.md §7, model.md §2
    assert config.profile == "sep2023" and config.rate == pytest.approx(1000.0 / 36)
    assert config.sigma_a_eq == (1.01540197, 1.01540197)  # the logbook: one value for both rods
    ref = config.reference
    np.testing.assert_allclose(ref.p_des[[0, 2]], [[0.0, 0.120], [-0.035, 0.122]])  # §2 FPU list
    np.testing.assert_allclose(ref.t, np.arange(11) * 10.0)
    assert ref.duration == pytest.approx(110.0)
    schedule = run_schedule(run)
    assert schedule["trajectory"] == "steps" and schedule["times"] == list(ref.t)
    assert schedule["rate"] == pytest.approx(0.1)


def _disc(folder: Path, name: str) -> Path:
    """A dark disc on a light background, written as ``name`` (a stand-in for an asset)."""
    image = np.full((400, 400, 3), 255, np.uint8)
    cv2.circle(image, (200, 200), 150, (0, 0, 0), -1)
    cv2.imwrite(str(folder / name), image)
    return folder / name


def test_a_contour_run_needs_its_image_and_plays_it_at_8_hz(tmp_path) -> None:
    run = catalogue.replayable("20231017_112545")  # bat L: r_max 0.030 m, k = 2
    with pytest.raises(ValueError, match="contour of bat.png .* no --image-dir given"):
        run.timed_reference()
    with pytest.raises(ValueError, match=f"not in {tmp_path}"):
        dataclasses.replace(run, image_dir=tmp_path).timed_reference()
    _disc(tmp_path, "bat.png")
    run = dataclasses.replace(run, image_dir=tmp_path)
    ref = run.timed_reference()
    np.testing.assert_allclose(np.diff(ref.t), 0.125)  # 8 Hz (experiments.md §3)
    radius = np.linalg.norm(ref.p_des - [0.0, 0.1285], axis=1)
    assert radius.max() == pytest.approx(0.030, abs=1e-9)  # the largest coordinate is r_max
    assert radius.min() > 0.029  # a disc: every point on the circle
    config = replay_config(run)
    assert config.profile == "oct2023" and config.reference is not None
    np.testing.assert_array_equal(config.reference.p_des, ref.p_des)
    schedule = run_schedule(run)
    assert schedule["trajectory"] == "contour" and schedule["image_path"] == str(
        tmp_path / "bat.png"
    )
    assert (schedule["radius"], schedule["contour_k"], schedule["rate"]) == (0.030, 2, 8.0)


def test_hsa_experiment_replays_a_catalogued_run_and_refuses_a_missing_image(
    tmp_path, capsys
) -> None:
    out = tmp_path / "payload"
    argv = ["--run", "20230925_142209", "--duration", "2", "--quiet", "--no-figures"]
    assert main([*argv, "--out", str(out)]) == 0
    with pytest.raises(SystemExit) as refused:
        main(["--run", "20230925_102428", "--out", str(tmp_path / "flame")])
    assert refused.value.code == 2
    err = capsys.readouterr().err
    assert "contour of tud_flame.jpeg" in err and len(err.splitlines()) == 1
    with pytest.raises(SystemExit) as refused:
        main(["--run", "20230925_142209", "--image-dir", str(tmp_path)])
    assert refused.value.code == 2
    assert "--image-dir applies to a contour run" in capsys.readouterr().err

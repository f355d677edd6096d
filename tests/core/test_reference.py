"""The packaged real-robot reference runs (hsa_core.runs.reference): every run loads with its
logbook conditions, the RMSE recomputed from its traces is the provenance README's, and the step
instants are where the reference moves."""

from __future__ import annotations

import dataclasses
import datetime

import numpy as np
import pytest

from hsa_core.controller.control import CollocatedGains, ControllerKind, PidGains
from hsa_core.runs import reference
from hsa_core.runs.profiles import VelocityEstimator, load_profile

README_RMSE = {
    "20230925_092200": 5.92,
    "20230925_093236": 4.18,
    "20230925_094023": 4.23,
    "20231019_143126": 3.67,
}
"""[mm] "RMSE from these traces", as the source README (shared/realdata/README.md) states them."""


def test_the_four_runs_are_packaged() -> None:
    assert reference.run_names() == tuple(sorted(README_RMSE))


@pytest.mark.parametrize("bag", sorted(README_RMSE))
def test_each_run_loads_its_series_and_the_rmse_of_its_traces_is_the_readme_s(bag: str) -> None:
    run = reference.load_run(bag)
    assert run.conditions.bag == bag
    n = len(run.t)
    assert (
        10_990 <= n <= 11_000 and np.allclose(np.diff(run.t), 0.01, atol=1e-6) and run.t[0] == 0.0
    )
    assert run.p.shape == run.p_des.shape == (n, 2) and np.all(np.isfinite(run.p))
    assert len(run.pee.t) > 700 and set(run.pee.columns) == {"px_des", "py_des", "px", "py"}
    assert {"phi1", "phi2"} <= set(run.phi.columns) and "kappa_be" in run.q.columns
    assert (run.varphi is None) == (run.conditions.law is ControllerKind.PID)
    assert list(run.step_metrics["step"]) == list(range(11))
    # the README's figures are rounded to 0.01 mm and were computed in a way it does not record:
    # within 0.5 %
    assert run.rmse() * 1e3 == pytest.approx(README_RMSE[bag], rel=5e-3)


def test_conditions_are_the_logbook_s() -> None:
    pid = reference.load_run("20230925_092200").conditions
    assert (pid.material, pid.law, pid.tanh_slope) == ("fpu", ControllerKind.PID, None)
    assert pid.gains == PidGains(10.0, 110.0, 0.25)
    assert pid.sigma_a_eq == (1.02775671, 1.02775671) and pid.payload == 0.0
    # the September profile with the run's own 38 ms ticks (runs.yaml; the test below)
    assert pid.date == datetime.date(2023, 9, 25) and pid.profile == dataclasses.replace(
        load_profile("sep2023"), control_period_ms=38
    )
    assert (
        pid.profile.bus_baud == 2_000_000
        and pid.profile.velocity_estimator is VelocityEstimator.SMOOTHING_SPLINE_16
    )
    gc = reference.load_run("20230925_094023").conditions
    assert gc.law is ControllerKind.PSATID_GC and gc.gains == CollocatedGains(
        0.3, 0.05, 0.02, 100.0
    )
    assert gc.tanh_slope == 100.0 and gc.sigma_a_eq == (1.00443883, 1.00443883)
    epu = reference.load_run("20231019_143126").conditions
    assert (epu.material, epu.law, epu.sigma_a_eq) == (
        "epu",
        ControllerKind.PSATID,
        (1.05440951, 1.04468428),
    )
    assert epu.profile == load_profile("oct2023") and epu.profile.control_period_ms == 25
    assert (
        epu.profile.bus_baud == 4_000_000
        and epu.profile.velocity_estimator is VelocityEstimator.SAVITZKY_GOLAY_20
    )


@pytest.mark.parametrize("bag", sorted(README_RMSE))
def test_step_instants_are_where_the_reference_changes(bag: str) -> None:
    run = reference.load_run(bag)
    steps = run.step_instants
    assert len(steps) == 10
    # the step-metrics table (computed from the plotted lines) starts the same steps within one 10
    # ms sample
    assert np.allclose(steps, run.step_metrics["t_start"][1:], atol=0.0101)
    for t_step in steps:
        k = int(np.argmin(np.abs(run.t - t_step)))
        assert np.linalg.norm(run.p_des[k] - run.p_des[k - 1]) > reference.STEP_THRESHOLD
        assert np.ptp(run.p_des[k : k + 50], axis=0).max() == 0.0  # held after it
    assert not np.allclose(np.diff(steps), 10.0, atol=0.05)  # not every 10 s: read, not assumed


def test_the_epu_reference_drift_is_no_step() -> None:
    t = np.arange(6) * 0.01
    # [m]
    p_des = (
        np.array([[0.0, 0.0], [0.0, 0.01], [0.0, 0.02], [5.0, 0.02], [5.0, 0.03], [5.0, 0.03]])
        * 1e-3
    )
    assert list(reference.step_instants(t, p_des)) == [0.03]


def test_an_unknown_run_is_a_one_line_error() -> None:
    with pytest.raises(
        ValueError, match=r"^unknown reference run '20230925_000000'; known: 20230925_092200, "
    ) as err:
        reference.load_run("20230925_000000")
    assert "\n" not in str(err.value)


TICK_PERIODS_MS = {
    "20230925_092200": 38,
    "20230925_093236": 36,
    "20230925_094023": 36,
    "20231019_143126": 25,
}
"""Each run's control period [ms] as runs.yaml states it."""


@pytest.mark.parametrize("bag", sorted(TICK_PERIODS_MS))
def test_each_run_ticks_at_the_period_its_plotted_samples_show(bag: str) -> None:
    """The plotted points are real samples, one per tick where the plot kept them all (realdata
    README): the median of the one-period gaps (shorter than 1.4 x the 5th percentile of a trace's
    gaps) of the p, phi and q traces together is the run's period to within half a millisecond,
    and that period reaches the replay."""
    run = reference.load_run(bag)
    single = []
    for trace in (run.pee, run.phi, run.q):
        gaps = np.diff(trace.t) * 1e3
        single.extend(gaps[gaps < 1.4 * np.percentile(gaps, 5)])
    assert len(single) > 500
    assert abs(float(np.median(single)) - TICK_PERIODS_MS[bag]) < 0.5
    assert run.conditions.profile.control_period_ms == TICK_PERIODS_MS[bag]

"""The sim-versus-real measures (hsa_core.analysis.sim_to_real) on synthetic step runs whose answers
are known by construction: first-order responses to 11 setpoints at irregular instants, with
offsets, delays and ripples added."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hsa_core.analysis import sim_to_real
from hsa_core.analysis.sim_to_real import StepRun

# [m]
SETPOINTS = (
    np.array(
        [
            [0.0, 120.0],
            [4.8, 127.8],
            [-35.0, 122.0],
            [-7.8, 130.2],
            [8.2, 114.6],
            [-14.2, 123.9],
            [0.0, 140.0],
            [25.2, 130.4],
            [-6.0, 139.9],
            [7.3, 114.8],
            [5.7, 127.1],
        ]
    )
    * 1e-3
)
# [s], not every 10 s
INSTANTS = np.array([9.87, 19.55, 29.96, 39.91, 49.51, 59.88, 69.93, 79.45, 89.90, 99.55])


def step_run(
    dt: float = 0.01,
    tau: float = 0.2,
    shift: float = 0.0,
    offset=(0.0, 0.0),
    end: float = 110.0,
    ripple: float = 0.0,
) -> StepRun:
    """Samples every dt of a first-order response (time constant tau) to SETPOINTS switched at
    INSTANTS + shift, plus a constant offset and an alternating ± ripple on x (sample by sample)."""
    t = np.round(np.arange(0.0, end, dt), 9)
    instants = INSTANTS + shift
    k = np.searchsorted(instants, t, side="right")  # setpoint index in force
    p_des = SETPOINTS[k]
    p = p_des.copy()
    for i, t_k in enumerate(instants, start=1):
        m = k == i
        p[m] = (
            SETPOINTS[i] + (SETPOINTS[i - 1] - SETPOINTS[i]) * np.exp(-(t[m] - t_k) / tau)[:, None]
        )
    p = p + np.asarray(offset)
    p[:, 0] += ripple * (-1.0) ** np.arange(len(t))
    return StepRun(t, p, p_des, end)


def test_identical_runs_are_zero_apart() -> None:
    c = sim_to_real.compare(step_run(), step_run())
    assert (
        c.deviation == 0.0 and c.response_time_difference == 0.0 and c.rise_time_difference == 0.0
    )
    assert (
        c.rmse[0] == c.rmse[1] and c.end_error[0] == c.end_error[1] and c.x_peak_to_peak[0] < 1e-15
    )


def test_each_run_is_aligned_at_its_own_step_instants() -> None:
    ref = step_run()
    late = step_run(dt=0.005, shift=0.3)  # the same responses, 0.3 s later, sampled twice as often
    np.testing.assert_allclose(late.step_starts, INSTANTS + 0.3)
    assert sim_to_real.deviation(late, ref) < 1e-12
    assert sim_to_real.response_times(late) == pytest.approx(
        sim_to_real.response_times(ref), abs=1e-12
    )


def test_deviation_of_a_constant_offset_is_its_length() -> None:
    off = step_run(offset=(3e-4, 4e-4))
    assert sim_to_real.deviation(off, step_run()) == pytest.approx(5e-4, rel=1e-12)
    assert sim_to_real.aligned_responses(off).shape == (10, 930, 2)  # steps 1-10, 9.3 s at 100 Hz


def test_end_error_and_peak_to_peak_of_the_last_two_seconds() -> None:
    run = step_run(offset=(3e-4, 4e-4), ripple=2e-4)
    np.testing.assert_allclose(sim_to_real.end_peak_to_peak(run), [[4e-4, 0.0]] * 10, atol=1e-12)
    # ‖e‖ of an alternating (0.3 ± 0.2, 0.4) mm offset: the mean of its two lengths
    expected = (math.hypot(5e-4, 4e-4) + math.hypot(1e-4, 4e-4)) / 2
    np.testing.assert_allclose(sim_to_real.end_error(run), expected, rtol=1e-9)
    c = sim_to_real.compare(run, step_run())
    assert c.x_peak_to_peak == pytest.approx((4e-4, 0.0), abs=1e-12)
    assert c.end_error[0] == pytest.approx(expected, rel=1e-9) and c.end_error[1] < 1e-12


def test_response_time_is_the_first_sample_below_ten_percent() -> None:
    # e = e0 exp(−t/τ) < 0.1 e0 from t = τ ln 10 on: the first 10 ms sample after it
    fast, slow = step_run(tau=0.2), step_run(tau=0.3)
    # 0.2 ln 10 = 0.4605
    np.testing.assert_allclose(sim_to_real.response_times(fast), 0.47, atol=1e-9)
    # 0.3 ln 10 = 0.6908
    np.testing.assert_allclose(sim_to_real.response_times(slow), 0.70, atol=1e-9)
    assert sim_to_real.compare(slow, fast).response_time_difference == pytest.approx(0.23 / 0.47)


def test_rise_time_is_ten_to_ninety_percent_of_the_way() -> None:
    # progress 1 − exp(−t/τ): 10 % at τ ln(10/9), 90 % at τ ln 10; each at the first 10 ms sample
    # after it
    fast, slow = step_run(tau=0.2), step_run(tau=0.3)
    # 0.0211 → 0.03, 0.4605 → 0.47
    np.testing.assert_allclose(sim_to_real.rise_times(fast), 0.47 - 0.03, atol=1e-9)
    # 0.0316 → 0.04, 0.6908 → 0.70
    np.testing.assert_allclose(sim_to_real.rise_times(slow), 0.70 - 0.04, atol=1e-9)
    assert sim_to_real.compare(slow, fast).rise_time_difference == pytest.approx(0.22 / 0.44)


def test_onset_time_is_the_first_sample_at_ten_percent_of_the_way() -> None:
    # progress 1 − exp(−t/τ) reaches 10 % at τ ln(10/9): 0.0211 s → the 0.03 s sample (τ 0.2),
    # 0.0316 → 0.04 (τ 0.3)
    np.testing.assert_allclose(sim_to_real.onset_times(step_run(tau=0.2)), 0.03, atol=1e-9)
    np.testing.assert_allclose(sim_to_real.onset_times(step_run(tau=0.3)), 0.04, atol=1e-9)


def test_rmse_of_a_constant_error() -> None:
    run = StepRun(np.arange(4.0), np.zeros((4, 2)), np.tile([3e-3, 4e-3], (4, 1)), end=3.0)
    assert sim_to_real.rmse(run) == pytest.approx(5e-3)


def test_bad_runs_are_one_line_errors() -> None:
    with pytest.raises(ValueError, match=r"^p and p_des must be \(3, 2\)"):
        StepRun(np.arange(3.0), np.zeros((3, 2)), np.zeros((2, 2)), 3.0)
    with pytest.raises(ValueError, match="increasing"):
        StepRun(np.array([0.0, 0.0, 1.0]), np.zeros((3, 2)), np.zeros((3, 2)), 3.0)
    short = step_run(end=45.0)
    with pytest.raises(ValueError, match=r"^the run has 5 steps, 11 are compared$"):
        sim_to_real.deviation(short, step_run())
    with pytest.raises(
        ValueError, match=r"^the run ends at 104\.99 s, before 9\.3 s after the step at 99\.55 s$"
    ):
        sim_to_real.aligned_responses(step_run(end=105.0))


def overshooting_run(past: float, across: float = 0.0) -> StepRun:
    """The setpoints of step_run, followed exactly except for the first second of every step, where
    p sits ``past`` beyond the new setpoint along the step's direction and ``across`` to its
    left."""
    run = step_run()
    p = run.p_des.copy()
    for i, t_k in enumerate(INSTANTS, start=1):
        d = (SETPOINTS[i] - SETPOINTS[i - 1]) / np.linalg.norm(SETPOINTS[i] - SETPOINTS[i - 1])
        m = (run.t >= t_k) & (run.t < t_k + 1.0)
        p[m] = SETPOINTS[i] + past * d + across * np.array([-d[1], d[0]])
    return StepRun(run.t, p, run.p_des, run.end)


def test_overshoot_is_the_distance_past_the_setpoint_along_the_step() -> None:
    np.testing.assert_allclose(sim_to_real.overshoots(overshooting_run(0.002)), 0.002, rtol=1e-9)
    # an error across the step direction is not an overshoot; falling short is none either
    np.testing.assert_allclose(
        sim_to_real.overshoots(overshooting_run(0.002, across=0.005)), 0.002, rtol=1e-9
    )
    np.testing.assert_array_equal(sim_to_real.overshoots(overshooting_run(-0.003)), 0.0)


def test_deviation_per_step_and_the_side_by_side_table() -> None:
    reference = step_run()
    shifted = step_run(offset=(0.003, 0.004))
    np.testing.assert_allclose(sim_to_real.step_deviations(shifted, reference), 0.005, rtol=1e-12)
    table = sim_to_real.step_table(shifted, reference)
    assert table.steps == sim_to_real.STEPS
    np.testing.assert_allclose(table.start[0], INSTANTS, atol=1e-9)
    np.testing.assert_allclose(table.start[1], INSTANTS, atol=1e-9)
    # the offset, once the response has settled
    np.testing.assert_allclose(table.end_error[0], 0.005, rtol=1e-6)
    np.testing.assert_allclose(table.end_error[1], 0.0, atol=1e-12)
    # first order: τ ln 9
    np.testing.assert_allclose(table.rise_time[1], 0.2 * math.log(9.0), atol=0.011)
    rows = table.rows()
    assert [r["step"] for r in rows] == list(range(1, 11))
    assert rows[0]["deviation"] == pytest.approx(0.005)
    assert rows[0]["peak_to_peak"]["run"] == pytest.approx([0.0, 0.0], abs=1e-6)
    d = np.diff(SETPOINTS, axis=0) / np.linalg.norm(np.diff(SETPOINTS, axis=0), axis=1)[:, None]
    # settles there
    np.testing.assert_allclose(table.overshoot[0], np.maximum(0.0, d @ [0.003, 0.004]), atol=1e-9)
    # a first-order response never passes its target
    np.testing.assert_array_equal(table.overshoot[1], 0.0)


def test_realizations_split_into_a_systematic_and_a_random_part() -> None:
    # Two realizations 1 mm to either side in x of a run 2 mm off in y: their mean is the run, 2 mm
    # from the reference (systematic); each is 1 mm from the mean (spread); each is √5 mm off.
    ref = step_run()
    runs = [step_run(offset=(dx, 2e-3)) for dx in (-1e-3, 1e-3)]
    split = sim_to_real.split_realizations(runs, ref)
    assert split.systematic == pytest.approx(2e-3, rel=1e-9)
    assert split.spread == pytest.approx(1e-3, rel=1e-9)
    assert split.rms == pytest.approx(math.sqrt(5) * 1e-3, rel=1e-9)
    assert split.systematic_per_step == pytest.approx(np.full(10, 2e-3), rel=1e-9)
    # A slower realization differs just after its steps, not 5 s on.
    late = sim_to_real.split_realizations([step_run(tau=0.3)], ref, window=(5.0, 9.3))
    early = sim_to_real.split_realizations([step_run(tau=0.3)], ref, window=(0.0, 0.5))
    assert late.systematic < 1e-6 < early.systematic
    assert late.spread == early.spread == 0.0
    with pytest.raises(ValueError, match="window"):
        sim_to_real.split_realizations(runs, ref, window=(1.0, 10.0))
    with pytest.raises(ValueError, match="realizations"):
        sim_to_real.split_realizations([], ref)


def contour_run(delay: float, offset=(0.0, 0.0), lag: float = 0.0) -> StepRun:
    """A circle of 20 mm radius traced once in 30 s from ``delay`` (at rest at its first point
    before and its last after, until 40 s), followed ``lag`` s late, plus a constant ``offset``."""
    t = np.round(np.arange(0.0, 40.0, 0.01), 9)

    def circle(s: np.ndarray) -> np.ndarray:
        a = 2 * math.pi * np.clip(s, 0.0, 30.0) / 30.0
        return np.stack([0.02 * np.sin(a), 0.12 + 0.02 * (1 - np.cos(a))], axis=1)

    return StepRun(t, circle(t - delay - lag) + np.asarray(offset), circle(t - delay), 40.0)


def test_a_contour_is_aligned_on_its_setpoints_and_compared_where_both_exist() -> None:
    ref = contour_run(2.0)
    run = contour_run(3.5, offset=(0.0, 1e-3))  # starts 1.5 s later in its own log, 1 mm off
    c = sim_to_real.contour_deviation(run, ref)
    assert c.shift == pytest.approx(1.5, abs=1e-9)
    assert c.setpoint_match == pytest.approx(0.0, abs=1e-12)
    assert c.deviation == pytest.approx(1e-3, rel=1e-9)
    assert c.rmse == pytest.approx((1e-3, 0.0), abs=1e-12)
    assert c.covered == pytest.approx(1 - 1.5 / 40.0, abs=0.001)
    # a run that lags its setpoints is that far from a reference that does not
    lagging = sim_to_real.contour_deviation(contour_run(2.0, lag=0.5), ref)
    speed = 2 * math.pi * 0.02 / 30.0  # [m/s] along the circle
    assert lagging.shift == pytest.approx(0.0, abs=1e-9)
    assert lagging.deviation == pytest.approx(speed * 0.5 * math.sqrt(30.0 / 40.0), rel=0.01)
    # ... and the reference leads it by those 0.5 s, where the two coincide
    assert lagging.lag == pytest.approx(-0.5, abs=1e-9)
    assert lagging.deviation_at_lag < 1e-9
    assert c.lag == pytest.approx(0.0, abs=1e-9)
    assert c.deviation_at_lag == pytest.approx(1e-3, rel=1e-9)
    short = StepRun(ref.t[:1000], ref.p[:1000], ref.p_des[:1000], 10.0)  # a quarter of it
    with pytest.raises(ValueError, match="overlap"):
        sim_to_real.contour_deviation(short, ref)

"""Tests of hsa_core.analysis.metrics on signals whose metrics are known by construction
(experiments.md §4)."""

import math

import numpy as np
import pytest

from hsa_core.analysis.metrics import (
    control_rate,
    evaluate_run,
    format_steps,
    format_summary,
    saturation_mask,
    step_bounds,
    tracking_rmse,
)

DT = 0.025  # 40 Hz


def step_run(targets, response, period=10.0, dt=DT, t0=123.0):
    """Tick log for a step list: p_ee(t) = target + (previous − target)·response(t − t_change)."""
    n = int(round(len(targets) * period / dt))
    t = t0 + dt * np.arange(n)
    k = np.minimum((np.arange(n) * dt // period).astype(int), len(targets) - 1)
    targets = np.asarray(targets, dtype=float)
    p_des = targets[k]
    # the first step starts 10 mm away
    start = np.vstack([targets[:1] + [0.0, -0.01], targets[:-1]])[k]
    tau = dt * np.arange(n) - k * period
    p_ee = p_des + (start - p_des) * response(tau)[:, None]
    return t, p_des, p_ee


def first_index_time(condition, dt=DT):
    """Time of the first tick (0, dt, 2dt, …) where condition(time) holds."""
    j = 0
    while not condition(j * dt):
        j += 1
    return j * dt


TARGETS = [[0.0, 0.12], [0.02, 0.125], [-0.01, 0.11], [0.0, 0.14], [0.015, 0.13]]


def test_first_order_response_time_is_tau_ln10():
    tau = 0.4
    t, p_des, p_ee = step_run(TARGETS, lambda s: np.exp(-s / tau))
    run = evaluate_run(t, p_des, p_ee)
    expected = first_index_time(lambda s: math.exp(-s / tau) < 0.1)  # first tick after τ·ln 10
    assert abs(expected - tau * math.log(10)) < DT
    assert len(run.steps) == 5
    for s in run.steps:
        assert s.response_time == pytest.approx(expected)
        assert s.overshoot == 0.0 and s.overshoot_percent == 0.0
        # e0·exp(−8 s/τ) bounds the last 2 s
        assert s.steady_state_error < s.initial_error * math.exp(-8.0 / tau)
    assert run.response_time_mean == pytest.approx(expected) and run.n_not_reached == 0


def test_settling_time_uses_max_of_10_percent_and_1_mm():
    tau = 0.3
    # step sizes: 10 mm (first), then 25 mm and ~5 mm; band = max(0.1·e0, 1 mm)
    targets = [[0.0, 0.12], [0.0, 0.145], [0.003, 0.141]]
    t, p_des, p_ee = step_run(targets, lambda s: np.exp(-s / tau))
    run = evaluate_run(t, p_des, p_ee)
    big, small = run.steps[1], run.steps[2]
    assert big.initial_error == pytest.approx(0.025)
    assert big.settling_time == pytest.approx(
        first_index_time(lambda s: 0.025 * math.exp(-s / tau) <= 0.0025)
    )
    assert small.initial_error == pytest.approx(0.005)
    assert small.settling_time == pytest.approx(
        first_index_time(lambda s: 0.005 * math.exp(-s / tau) <= 0.001)
    )
    assert small.settling_time < small.response_time  # the 1 mm floor is wider than 10 % of 5 mm


def test_overshoot_of_underdamped_second_order_response():
    zeta, omega = 0.3, 6.0
    wd = omega * math.sqrt(1 - zeta**2)

    def response(s):
        return np.exp(-zeta * omega * s) * (
            np.cos(wd * s) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * s)
        )

    dt = 0.001
    targets = [[0.0, 0.12], [0.012, 0.136]]  # 20 mm step along (0.6, 0.8)
    t, p_des, p_ee = step_run(targets, response, dt=dt)
    # an error across the step direction must not count as overshoot
    across = np.array([-0.8, 0.6]) * 0.002 * np.sin(7.0 * t)[:, None]
    run = evaluate_run(t, p_des, p_ee + across)
    step = run.steps[1]
    # peak overshoot of a 2nd-order system
    expected_fraction = math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))
    assert step.step_size == pytest.approx(0.02)
    assert step.overshoot_percent == pytest.approx(100 * expected_fraction, rel=1e-3)
    assert step.overshoot == pytest.approx(0.02 * expected_fraction, rel=1e-3)


def test_constant_offset_gives_known_rmse_and_steady_state_error():
    t, p_des, _ = step_run(TARGETS, lambda s: 0 * s)
    p_ee = p_des + [0.003, -0.004]  # 5 mm everywhere
    run = evaluate_run(t, p_des, p_ee)
    assert run.rmse == pytest.approx(0.005)
    assert tracking_rmse(p_des, p_ee) == pytest.approx(0.005)
    assert run.steady_state_error_mean == pytest.approx(0.005)
    assert all(s.steady_state_error == pytest.approx(0.005) for s in run.steps)
    assert all(math.isnan(s.settling_time) for s in run.steps)  # never within the 1 mm band


def test_rmse_mixes_errors_quadratically_and_trims_to_duration():
    t = DT * np.arange(8000)  # 200 s
    p_des = np.zeros((8000, 2))
    p_ee = np.zeros((8000, 2))
    p_ee[: 4400 // 2, 0] = 0.002  # first 55 s: 2 mm
    p_ee[4400 // 2 : 4400, 1] = 0.004  # next 55 s: 4 mm
    p_ee[4400:, 0] = 1.0  # beyond 110 s: huge, must be trimmed away
    run = evaluate_run(t + 7.0, p_des, p_ee, duration=110.0)
    assert run.n_ticks == 4400
    assert run.rmse == pytest.approx(math.sqrt((0.002**2 + 0.004**2) / 2))


def test_steady_state_window_is_last_two_seconds_of_each_step():
    t, p_des, _ = step_run(TARGETS, lambda s: 0 * s)
    tau = (t - t[0]) % 10.0
    p_ee = p_des + np.where(tau >= 8.0, 0.001, 0.01)[:, None] * [1.0, 0.0]
    run = evaluate_run(t, p_des, p_ee)
    assert all(s.steady_state_error == pytest.approx(0.001) for s in run.steps)


def test_response_not_reached_is_nan_and_counted():
    t, p_des, p_ee = step_run(TARGETS, lambda s: np.exp(-s / 20.0))  # far too slow for 10 s steps
    run = evaluate_run(t, p_des, p_ee)
    assert all(math.isnan(s.response_time) for s in run.steps)
    assert math.isnan(run.response_time_mean) and run.n_not_reached == 4
    assert "4 n.r." in format_summary([run])


def test_summary_means_exclude_the_first_step():
    t, p_des, p_ee = step_run(TARGETS, lambda s: np.exp(-s / 0.1))
    first = slice(0, int(round(10.0 / DT)))  # the first step responds 20× slower
    p_ee[first] = p_des[first] + [0.0, -0.01] * np.exp(-(t[first] - t[0]) / 2.0)[:, None]
    run = evaluate_run(t, p_des, p_ee)
    assert run.steps[0].response_time == pytest.approx(
        first_index_time(lambda s: math.exp(-s / 2.0) < 0.1)
    )
    assert run.response_time_mean == pytest.approx(
        first_index_time(lambda s: math.exp(-s / 0.1) < 0.1)
    )


def test_saturation_rate_and_step_detection():
    phi = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 3.4906585], [-0.2, 4.0], [1.0, 2.0]])
    np.testing.assert_array_equal(saturation_mask(phi, 3.4906585), [True, False, True, True, False])
    t = 0.5 + np.array([0.0, 0.025, 0.05, 0.1, 0.125])
    assert control_rate(t) == pytest.approx(4 / 0.125)
    p_des = np.array([[0, 1], [0, 1], [1, 1], [1, 1], [0, 1]], dtype=float)
    assert step_bounds(p_des) == [(0, 2), (2, 4), (4, 5)]
    run = evaluate_run(t, p_des, p_des, saturated=saturation_mask(phi, 3.4906585))
    assert run.saturated_fraction == pytest.approx(0.6) and run.control_rate == pytest.approx(32.0)


def test_formatted_tables_contain_the_numbers_in_mm():
    t, p_des, _ = step_run(TARGETS, lambda s: 0 * s)
    run = evaluate_run(t, p_des, p_des + [0.003, -0.004], name="PID")
    text = format_summary([run])
    assert "PID" in text and "5.00" in text and "RMSE [mm]" in text and "40.0" in text
    steps = format_steps(run)
    assert len(steps.splitlines()) == 2 + len(TARGETS) and "125.00" in steps  # y^d = 0.125 m


def test_bad_inputs_rejected():
    with pytest.raises(ValueError):
        evaluate_run([0.0, 0.0, 1.0], np.zeros((3, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError):
        evaluate_run([0.0, 1.0], np.zeros((2, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError):
        evaluate_run([0.0, 1.0], np.zeros((2, 2)), np.zeros((2, 2)), saturated=[True])
    with pytest.raises(ValueError):
        evaluate_run([0.0, 1.0], np.zeros((2, 2)), np.zeros((2, 2)), duration=0.0)

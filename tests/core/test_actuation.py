"""Tests of hsa_core.model.actuation: φ ↔ ψ ↔ Dynamixel ticks, goal limits and rate limit (spec
§7–§8)."""

import math

import numpy as np
import pytest

from hsa_core.model.actuation import (
    DEFAULT_MAX_GOAL_RATE,
    MotorLimits,
    MotorMap,
    RejectionLog,
    accept_read_neutral,
    angles_to_ticks,
    limit_goal_rate,
    neutral_check,
    ticks_to_angles,
)

NEUTRAL = (2048, -5000, 123456, 0)
TICK = math.pi / 2048  # rad per tick (4096 per revolution)
PHI_MAX = math.radians(200.0)  # the FPU set's


@pytest.fixture
def motor_map():
    return MotorMap(neutral_ticks=NEUTRAL, phi_max=PHI_MAX)


def test_defaults_follow_spec_wiring():
    m = MotorMap(phi_max=PHI_MAX)
    assert m.ids == (21, 22, 23, 24)
    assert m.rho == (1, -1, 1, -1) and m.h == (1, 1)
    assert m.phi_max == PHI_MAX


def test_a_map_has_no_default_twist_limit():
    """The twist limit comes from the parameter set (Wiring.motor_map), never from a default of the
    map."""
    with pytest.raises(TypeError, match="phi_max"):
        MotorMap()


def test_spec_mapping_of_phi_to_motor_angles(motor_map):
    # spec §7: [ψ21, ψ22, ψ23, ψ24] = [+φ2, −φ2, +φ1, −φ1]
    np.testing.assert_array_equal(motor_map.motor_angles([1.25, 2.5]), [2.5, -2.5, 1.25, -1.25])


def test_handedness_phi1_drives_motors_23_24_phi2_drives_21_22(motor_map):
    neutral = np.array(NEUTRAL)
    only_phi1 = motor_map.goal_ticks([1.0, 0.0]) - neutral
    only_phi2 = motor_map.goal_ticks([0.0, 1.0]) - neutral
    moved1 = {i for i, d in zip(motor_map.ids, only_phi1) if d != 0}
    moved2 = {i for i, d in zip(motor_map.ids, only_phi2) if d != 0}
    assert moved1 == {23, 24} and moved2 == {21, 22}
    assert only_phi1[2] > 0 > only_phi1[3]  # ρ23 = +1, ρ24 = −1
    assert only_phi2[0] > 0 > only_phi2[1]  # ρ21 = +1, ρ22 = −1


def test_control_handedness_flips_the_rod():
    m = MotorMap(h=(-1, 1), phi_max=PHI_MAX)
    np.testing.assert_array_equal(m.motor_angles([1.0, 2.0]), [2.0, -2.0, -1.0, 1.0])
    np.testing.assert_allclose(m.rod_twists(m.motor_angles([1.0, 2.0])), [1.0, 2.0])


def test_ticks_formula_truncates_towards_zero():
    # goal = neutral + trunc(ψ·2048/π): 1.7 ticks → 1, −1.7 ticks → −1, exact 2048 ticks = π
    np.testing.assert_array_equal(
        angles_to_ticks([1.7 * TICK, -1.7 * TICK, math.pi, -math.pi], [10] * 4),
        [11, 9, 10 + 2048, 10 - 2048],
    )
    assert angles_to_ticks([0.0], [5]).dtype == np.int32
    np.testing.assert_allclose(
        ticks_to_angles([2048 + 100, 100 - 4096], [100, 100]), [math.pi, -2 * math.pi]
    )


def test_non_finite_or_huge_angles_raise_instead_of_wrapping(motor_map):
    for phi in ([math.nan, 0.0], [math.inf, 0.0], [1e7, 0.0]):
        with pytest.raises(ValueError):
            motor_map.goal_ticks(phi)


def test_multi_turn_ticks_do_not_wrap():
    psi = 3.0 * 2.0 * math.pi + 0.5  # more than three revolutions
    ticks = angles_to_ticks([psi], [0])
    assert ticks[0] == math.trunc(psi * 2048 / math.pi) > 4096 * 3


def test_round_trip_phi_ticks_phi_within_one_tick(motor_map):
    rng = np.random.default_rng(0)
    for phi in rng.uniform(0.0, motor_map.phi_max, size=(500, 2)):
        back = motor_map.present_twists(motor_map.goal_ticks(phi))
        assert np.all(np.abs(back - phi) < TICK)
        assert np.all(back <= phi + 1e-15)  # truncation never overshoots a positive twist


def test_round_trip_ticks_phi_ticks_exact(motor_map):
    rng = np.random.default_rng(1)
    neutral = np.array(NEUTRAL)
    for d1, d2 in rng.integers(-(2**20), 2**20, size=(2000, 2)):
        ticks = neutral + np.array([d2, -d2, d1, -d1])  # consistent pairs, as the map produces them
        np.testing.assert_array_equal(motor_map.goal_ticks(motor_map.present_twists(ticks)), ticks)
    every = np.arange(-5000, 5000)
    np.testing.assert_array_equal(angles_to_ticks(ticks_to_angles(every, 0), 0), every)


def test_limits_never_exceeded(motor_map):
    limits = MotorLimits.from_map(motor_map)
    span = math.ceil((motor_map.phi_max + motor_map.margin) * 2048 / math.pi)
    margin = math.ceil(motor_map.margin * 2048 / math.pi)
    neutral = np.array(NEUTRAL)
    # + motors (21, 23) may go up by φ_max, − motors (22, 24) down, each with the small margin
    np.testing.assert_array_equal(limits.upper - neutral, [span, margin, span, margin])
    np.testing.assert_array_equal(neutral - limits.lower, [margin, span, margin, span])
    rng = np.random.default_rng(2)
    for phi in rng.uniform(-10.0, 10.0, size=(500, 2)):
        goal, clipped = limits.clamp(motor_map.goal_ticks(phi))
        assert np.all(limits.contains(goal)) and goal.dtype == np.int32
        twists = motor_map.present_twists(goal)
        assert np.all(twists >= -motor_map.margin - TICK)
        assert np.all(twists <= motor_map.phi_max + motor_map.margin + TICK)
        lo, hi = -motor_map.margin, motor_map.phi_max + motor_map.margin
        if np.all(
            (np.abs(phi - lo) > 2 * TICK) & (np.abs(phi - hi) > 2 * TICK)
        ):  # away from the rounded edges
            outside = (phi < lo) | (phi > hi)
            np.testing.assert_array_equal(clipped, outside[[1, 1, 0, 0]])


def test_limits_do_not_touch_valid_goals(motor_map):
    limits = MotorLimits.from_map(motor_map)
    for phi in ([0.0, 0.0], [motor_map.phi_max, 0.0], [1.0, 2.0]):
        goal = motor_map.goal_ticks(phi)
        clamped, clipped = limits.clamp(goal)
        np.testing.assert_array_equal(clamped, goal)
        assert not clipped.any()


def test_rate_limit():
    dt, rate = 0.025, 2 * math.pi  # spec §5 example: ≤ 2π rad/s at 40 Hz → ⌊0.157 rad⌋ = 102 ticks
    max_step = math.floor(rate * dt * 2048 / math.pi)
    assert max_step == 102
    previous = np.array([0, 100, -100, 5000])
    new = np.array([1000, 150, -1000, 4800])
    np.testing.assert_array_equal(limit_goal_rate(previous, new, dt, rate), [102, 150, -202, 4898])
    np.testing.assert_array_equal(limit_goal_rate(previous, previous, dt, rate), previous)
    with pytest.raises(ValueError):
        limit_goal_rate(previous, new, -1.0, rate)


def test_neutral_deviation_for_start_up_check(motor_map):
    present = np.array(NEUTRAL) + [0, 3, -2048, 0]
    np.testing.assert_allclose(motor_map.neutral_deviation(present), [0.0, 3 * TICK, -math.pi, 0.0])


def test_invalid_maps_rejected():
    with pytest.raises(ValueError):
        MotorMap(neutral_ticks=(0, 0, 0), phi_max=PHI_MAX)
    with pytest.raises(ValueError):
        MotorMap(rho=(1, 1, 2, -1), phi_max=PHI_MAX)
    with pytest.raises(ValueError):
        MotorMap(rod=(0, 0, 0, 0), phi_max=PHI_MAX)
    with pytest.raises(ValueError):
        MotorMap(phi_max=-1.0)


def test_default_goal_rate_is_twice_the_mx28_no_load_speed():
    # ROBOTIS e-Manual: 55 rev/min at 12 V; the paper's servo motions cannot be faster than that
    assert DEFAULT_MAX_GOAL_RATE == pytest.approx(2 * 55 * 2 * math.pi / 60)
    assert DEFAULT_MAX_GOAL_RATE > 55 * 2 * math.pi / 60


def test_neutral_check_at_rest_passes_twisted_only_while_held():
    assert neutral_check([0.05, -0.1, 0.0, 0.0], 0.1, held=False) is None
    problem = neutral_check([1.0, -1.0, 0.0, 0.0], 0.1, held=False)
    assert problem is not None and "untwist the robot or re-home" in problem and "\n" not in problem
    # a driver restart: the servos were held
    assert neutral_check([1.0, -1.0, 0.0, 0.0], 0.1, held=True) is None


def test_read_neutral_is_accepted_only_near_the_configured_one():
    configured = (2048, 2048, 2048, 2048)
    # 52 ticks = 0.08 rad
    assert accept_read_neutral((2050, 2040, 2048, 2100), configured, 0.1) is None
    problem = accept_read_neutral((2700, 1396, 2048, 2048), configured, 0.1)  # twisted by 1 rad
    assert problem is not None and "configured neutral" in problem


def test_limits_depend_on_the_configured_neutral_only():
    """The goal clamp of a φ command is the same whatever present positions exist: it is built from
    the map alone."""
    limits = MotorLimits.from_map(MotorMap(neutral_ticks=(2048,) * 4, phi_max=PHI_MAX))
    upper = 2048 + math.ceil((math.radians(200) + 0.02) * 2048 / math.pi)
    assert limits.upper[0] == upper and limits.lower[1] == 2048 - upper + 2048


def test_rejection_log_throttles_and_counts():
    log = RejectionLog(period=5.0)
    first = log.record("rejected", "nan", 0.0)
    assert first is not None and "rejected" in first
    assert all(log.record("rejected", "nan", 0.001 * k) is None for k in range(1, 1000))
    other = log.record("clipped", "phi 9", 0.5)  # another kind is not held back by the first
    assert other is not None
    summary = log.record("rejected", "inf", 5.0)
    assert summary is not None and summary.startswith("1000 rejected") and "inf" in summary
    assert log.record("rejected", "nan", 6.0) is None

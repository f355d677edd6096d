"""Tests of hsa_core.driver.servo_supervision's instant-wise goal-rate limiter and reboot admission
(issues 11, 12), and of the driver's goal pipeline (hsa_dynamixel_driver.goals); the supervisor
state machine is in test_servo_supervision.py.

Expected steps are computed here from the tick unit (4096 ticks per revolution) and the rate, not by
the code under test: max_rate · dt · 2048/π ticks, rounded down.
"""

import itertools
import math
import random

import numpy as np
import pytest

from hsa_core.driver.servo_supervision import reboot_refusal
from hsa_core.model.actuation import GoalRateLimiter, MotorLimits, MotorMap
from hsa_dynamixel_driver.goals import GoalPipeline

TICKS_PER_RAD = 2048 / math.pi
RATE = 10.0  # rad/s
PERIOD = 0.01  # s (100 Hz cycle)
STEP = 65  # ⌊10 rad/s · 0.01 s · 2048/π⌋ = ⌊65.19⌋ ticks per period
HELD = np.array([1000, 3000, -500, 5000])


def limiter_at(goal: np.ndarray, t: float) -> GoalRateLimiter:
    """A limiter whose goal ``goal`` was written at instant ``t`` (after a torque-on hold)."""
    limiter = GoalRateLimiter()
    limiter.reset(HELD)
    limiter.written(goal, t)
    return limiter


def write(limiter: GoalRateLimiter, target: np.ndarray, t: float) -> np.ndarray:
    """One write as the driver does it: the limited goal is written and recorded."""
    goal = limiter.limited(target, t, RATE, PERIOD)
    limiter.written(goal, t)
    return goal


def test_step_constant_is_the_rate_times_the_period() -> None:
    assert STEP == math.floor(RATE * PERIOD * TICKS_PER_RAD)


@pytest.mark.parametrize("order", list(itertools.permutations(range(3))))
def test_writes_at_one_instant_end_at_the_same_goal_in_any_order(order: tuple[int, ...]) -> None:
    # At t = 1.01 the cycle (old target A), a phi_cmd (target B) and the cycle again (target B)
    # write in some order; the last write decides, and it is measured from the goal of instant 1.00
    # whatever came before it.
    targets = [HELD + 500, HELD - 500, HELD + 20]
    limiter = limiter_at(HELD, 1.00)
    for k in order:
        final = write(limiter, targets[k], 1.01)
    expected = HELD + np.clip(targets[order[-1]] - HELD, -STEP, STEP)
    np.testing.assert_array_equal(final, expected)


def test_cycle_then_command_equals_command_then_cycle() -> None:
    # The driver's two paths at one simulated instant: the cycle rewrites the old target A, the
    # phi_cmd writes B; with the command first, the cycle then writes B again (its newest target).
    # Both end at B limited from 1.00.
    a, b = HELD + 300, HELD - 300
    first = limiter_at(HELD, 1.00)
    write(first, a, 1.01)
    write(first, b, 1.01)
    second = limiter_at(HELD, 1.00)
    write(second, b, 1.01)
    write(second, b, 1.01)
    np.testing.assert_array_equal(first.goal, second.goal)
    np.testing.assert_array_equal(first.goal, HELD - STEP)


def test_next_instant_is_measured_from_the_final_goal_of_the_previous_one() -> None:
    limiter = limiter_at(HELD, 1.00)
    write(limiter, HELD + 500, 1.01)
    write(limiter, HELD - 500, 1.01)  # final goal of 1.01: HELD - STEP
    np.testing.assert_array_equal(write(limiter, HELD - 500, 1.02), HELD - 2 * STEP)


def test_dt_is_capped_at_one_period_and_a_held_goal_moves_one_period_at_once() -> None:
    limiter = limiter_at(HELD, 1.00)
    # 2 s later: still one period
    np.testing.assert_array_equal(write(limiter, HELD + 5000, 3.00), HELD + STEP)
    fresh = GoalRateLimiter()
    fresh.reset(HELD)  # torque came on holding HELD: the first write may move a full period's step
    np.testing.assert_array_equal(write(fresh, HELD + 5000, 7.0), HELD + STEP)
    # same instant: from HELD again
    np.testing.assert_array_equal(write(fresh, HELD - 5000, 7.0), HELD - STEP)


def test_clock_jumping_back_allows_no_motion() -> None:
    limiter = limiter_at(HELD + 7, 5.0)
    np.testing.assert_array_equal(write(limiter, HELD + 5000, 4.0), HELD + 7)


def test_rate_zero_is_no_limit_and_clamp_is_applied() -> None:
    limiter = limiter_at(HELD, 1.0)
    np.testing.assert_array_equal(limiter.limited(HELD + 5000, 1.01, 0.0, PERIOD), HELD + 5000)
    clamped = limiter.limited(
        HELD + 5000, 1.01, RATE, PERIOD, clamp=lambda g: np.minimum(g, HELD + 10)
    )
    np.testing.assert_array_equal(clamped, HELD + 10)


def test_limited_before_reset_is_an_error() -> None:
    with pytest.raises(RuntimeError):
        GoalRateLimiter().limited(HELD, 0.0, RATE, PERIOD)


def test_flood_bound_holds_for_any_interleaving() -> None:
    # A flood of full-range swings at random instants, several writes per instant: every write stays
    # within RATE · min(t − t_prev, PERIOD) of the previous instant's final goal, and the final
    # goals of any two instants differ by at most RATE · Δt (the bound tests/ros/test_goal_flood.py
    # checks on the bus).
    rng = random.Random(3)
    limiter = GoalRateLimiter()
    limiter.reset(HELD)
    t, finals = 0.0, []
    for _ in range(400):
        t = round(t + rng.choice((0.0005, 0.001, 0.004, 0.01, 0.03)), 6)
        before = finals[-1] if finals else (-math.inf, HELD)
        for _ in range(rng.randint(1, 3)):
            target = HELD + rng.choice((-2300, 0, 2300))
            goal = write(limiter, target, t)
            allowed = math.floor(RATE * min(t - before[0], PERIOD) * TICKS_PER_RAD)
            assert np.all(np.abs(goal - before[1]) <= allowed)
        finals.append((t, limiter.goal))
    for (t_i, g_i), (t_j, g_j) in itertools.combinations(finals, 2):
        assert np.all(np.abs(g_j - g_i) <= RATE * (t_j - t_i) * TICKS_PER_RAD + 1e-9)


def test_reboot_refused_only_while_tracking_with_torque_on() -> None:
    assert "tracking" in reboot_refusal(active=True, link_up=True, torque_on=True, tracking=True)
    # holding
    assert reboot_refusal(active=True, link_up=True, torque_on=True, tracking=False) is None
    # torque off
    assert reboot_refusal(active=True, link_up=True, torque_on=False, tracking=True) is None
    assert reboot_refusal(active=True, link_up=True, torque_on=False, tracking=False) is None
    assert (
        reboot_refusal(active=False, link_up=True, torque_on=False, tracking=False)
        == "node is not active"
    )
    assert (
        reboot_refusal(active=True, link_up=False, torque_on=False, tracking=False)
        == "bus not connected"
    )


MAP = MotorMap(tuple(HELD.tolist()), (21, 22, 23, 24), phi_max=math.radians(200.0), margin=0.02)
LIMITS = MotorLimits.from_map(MAP)


class Command:
    """Stand-in for a PlanarActuation: phi and source_stamp."""

    def __init__(self, phi: list[float]) -> None:
        self.phi, self.source_stamp = phi, "stamp"


def pipeline_holding() -> GoalPipeline:
    """A pipeline whose servos hold HELD since torque-on."""
    goals = GoalPipeline()
    goals.limiter.reset(HELD)
    return goals


def test_pipeline_maps_a_command_to_goal_ticks_and_rate_limits_it() -> None:
    # φ = (0.1, 0.2) rad -> ψ = [+φ₂, −φ₂, +φ₁, −φ₁] -> ⌊0.2·2048/π⌋ = 130, ⌊0.1·2048/π⌋ = 65 ticks
    # from neutral
    goals = pipeline_holding()
    goals.take(Command([0.1, 0.2]))
    step = goals.next_goal(1.0, MAP, LIMITS, 0.0, PERIOD)
    np.testing.assert_array_equal(step.ticks, HELD + [130, -130, 65, -65])
    assert not step.rate_limited and step.clipped is None and goals.target_source == "stamp"
    goals = pipeline_holding()
    goals.take(Command([0.1, 0.2]))
    step = goals.next_goal(1.0, MAP, LIMITS, RATE, PERIOD)
    # 130 ticks shortened to 65
    np.testing.assert_array_equal(step.ticks, HELD + [STEP, -STEP, 65, -65])
    assert step.rate_limited


def test_pipeline_ramp_continues_then_stops_when_reached() -> None:
    goals = pipeline_holding()
    goals.take(Command([0.1, 0.2]))
    goals.written(goals.next_goal(1.0, MAP, LIMITS, RATE, PERIOD).ticks, 1.0)
    # the ramp's next step: not a new command
    step = goals.next_goal(1.01, MAP, LIMITS, RATE, PERIOD)
    np.testing.assert_array_equal(step.ticks, HELD + [130, -130, 65, -65])
    assert not step.rate_limited
    goals.written(step.ticks, 1.01)
    assert goals.next_goal(1.02, MAP, LIMITS, RATE, PERIOD) is None  # reached: nothing to write


def test_pipeline_clips_phi_and_drops_a_stale_target() -> None:
    goals = pipeline_holding()
    goals.take(Command([-1.0, 10.0]))
    step = goals.next_goal(1.0, MAP, LIMITS, 0.0, PERIOD)
    assert step.clipped is not None and "outside [0, 3.4907]" in step.clipped
    # ⌊(200° = 3.4907 rad)·2048/π⌋ = 2275
    np.testing.assert_array_equal(step.ticks, HELD + [2275, -2275, 0, 0])
    goals.drop_target()
    assert goals.next_goal(1.01, MAP, LIMITS, 0.0, PERIOD) is None

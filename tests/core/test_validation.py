"""Input validation against the physics (hsa_core.controller.validation) and the controller's
integrator guard (issue 10)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hsa_core.controller import control
from hsa_core.controller.control import Controller, ControllerKind
from hsa_core.controller.validation import (
    DelayGate,
    SetpointRejection,
    SetpointValidator,
    q_bounds,
    state_problem,
)
from hsa_core.model.params import load_params
from hsa_core.refusal import StateRejection
from hsa_core.task.planning import Planner, Setpoint

# FPU worked example of planning_and_control.md §2.2 (the spec's numbers, rounded to 8 digits)
GOOD = Setpoint(
    np.array([0.00479247, 0.12781018, -0.066980133]),
    np.array([-1.1352565, 0.0080816386, 0.30410104]),
    np.array([1.9846028, 1.6323408]),
    1e-16,
)
POISON = {
    "q_des 1e308": (
        dataclasses.replace(GOOD, q_des=np.array([1e308, 0.008, 0.304])),
        "implausible q",
    ),
    "q_des 1e9": (dataclasses.replace(GOOD, q_des=np.array([1e9, 1e9, 1e9])), "implausible q"),
    "kappa 1e3": (dataclasses.replace(GOOD, q_des=np.array([1e3, 0.008, 0.304])), "implausible q"),
    "phi_ss inconsistent": (
        dataclasses.replace(GOOD, phi_ss=np.array([1.6323408, 1.9846028])),
        "not an equilibrium",
    ),
    "phi_ss off by 10 mrad": (
        dataclasses.replace(GOOD, phi_ss=GOOD.phi_ss + 0.01),
        "not an equilibrium",
    ),
    "phi_ss above phi_max": (dataclasses.replace(GOOD, phi_ss=np.array([3.6, 1.6])), "phi_ss"),
    "optimality error -1": (dataclasses.replace(GOOD, optimality_error=-1.0), "optimality error"),
    "optimality error NaN": (
        dataclasses.replace(GOOD, optimality_error=math.nan),
        "optimality error",
    ),
    "chiee_des off by 1 cm": (
        dataclasses.replace(GOOD, chiee_des=GOOD.chiee_des + [0.01, 0.0, 0.0]),
        "FK(q_des)",
    ),
    "inf chiee_des": (
        dataclasses.replace(GOOD, chiee_des=np.array([math.inf, 0.12, 0.0])),
        "non-finite chiee_des",
    ),
}


@pytest.fixture(scope="module")
def params():
    return load_params("fpu")


@pytest.fixture(scope="module")
def validator(params):
    return SetpointValidator(params)


def test_worked_example_and_planner_output_are_accepted(params, validator) -> None:
    assert validator.problem(GOOD) is None
    planner = Planner(params)
    for p_des in ([0.0, 0.125], [0.012, 0.13], [-0.015, 0.12]):
        result = planner.plan(np.array(p_des))
        assert result.success
        assert validator.problem(result.setpoint) is None, p_des


@pytest.mark.parametrize("label", list(POISON))
def test_poison_setpoints_are_refused_with_the_reason(validator, label: str) -> None:
    setpoint, reason = POISON[label]
    problem = validator.problem(setpoint)
    assert problem is not None and reason in problem, problem


def test_q_bounds_follow_the_rod_length(params) -> None:
    low, high = q_bounds(params)
    assert high[0] == pytest.approx(0.5 * math.pi / 0.059) and low[0] == -high[0]
    longer = q_bounds(params.replace(l=2 * params.l))
    assert longer[1][0] == pytest.approx(high[0] / 2)


def test_states_with_absurd_magnitudes_are_refused(params) -> None:
    bounds = q_bounds(params)
    q, q_dot, chiee, chiee_dot = (
        [-1.1, 0.008, 0.3],
        [0.5, 0.0, 0.01],
        [0.005, 0.128, -0.07],
        [0.01, 0.0, 0.1],
    )
    assert state_problem(bounds, q, q_dot, chiee, chiee_dot, True) is None
    assert state_problem(bounds, [1e9, 0.0, 0.3], q_dot, chiee, chiee_dot, True).startswith(
        "implausible pose or configuration"
    )
    assert state_problem(bounds, q, q_dot, [math.nan, 0.1, 0.0], chiee_dot, True).startswith(
        "non-finite pose or configuration"
    )
    assert state_problem(bounds, q, [1e6, 0.0, 0.0], chiee, chiee_dot, True).startswith(
        "implausible rates"
    )
    assert state_problem(bounds, q, q_dot, chiee, [math.nan] * 3, True).startswith(
        "non-finite rates"
    )
    # rates NaN by contract
    assert state_problem(bounds, q, [math.nan] * 3, chiee, [math.nan] * 3, False) is None


def test_delay_gate_drops_samples_held_in_a_queue_and_accepts_a_new_latency() -> None:
    ms = 1_000_000
    gate = DelayGate(0.1, history=200)
    t = 0
    for _ in range(50):  # a regular 200 Hz stream, 3 ms latency plus 0-2 ms jitter
        t += 5 * ms
        assert not gate.late(t, t + 3 * ms + (t // ms) % 3 * ms)
    for k in range(5):  # samples stamped before a 2 s stall, delivered after it
        assert gate.late(t + k * ms, t + 2000 * ms + k * 10_000)
    assert not gate.late(t + 2000 * ms, t + 2003 * ms)  # the stream after the stall
    # a permanent latency step (e.g. a clock stepped at the source) is accepted after `history`
    offset = 500 * ms
    late = [
        gate.late(t + 2000 * ms + k * 5 * ms, t + 2003 * ms + k * 5 * ms + offset)
        for k in range(1, 300)
    ]
    assert late[0] and not any(late[200:])
    assert not DelayGate(0.0, 10).late(0, 10**12)  # disabled


# how fast the stalled node works through its backlog
@pytest.mark.parametrize("spacing_ms", [0.5, 4.0])
def test_delay_gate_drops_a_whole_backlog_longer_than_its_history(spacing_ms) -> None:
    """Issue 22: a 2 s stall of a node with a deep input queue (400 samples queued, history 200);
    the old gate let the backlog become its own reference after 200 late samples and passed states
    1-1.4 s old with a valid velocity."""
    ms = 1_000_000
    gate = DelayGate(0.1, history=200)
    t = 0
    for _ in range(300):
        t += 5 * ms
        assert not gate.late(t, t + 3 * ms)
    resume = t + 2000 * ms
    backlog = [gate.late(t + k * 5 * ms, resume + int(k * spacing_ms * ms)) for k in range(1, 401)]
    assert all(backlog), f"{backlog.count(False)} of 400 samples of the backlog passed"
    fresh = resume + 400 * int(spacing_ms * ms)
    assert not any(gate.late(fresh + k * 5 * ms, fresh + k * 5 * ms + 3 * ms) for k in range(10))


@pytest.mark.parametrize("kind", list(ControllerKind))
def test_integrators_stay_finite_and_bounded_by_design(params, kind: ControllerKind) -> None:
    c = Controller(kind, params)
    c.set_setpoint(GOOD)
    q, chiee = GOOD.q_des + [0.2, 0.0, 0.0], GOOD.chiee_des + [0.002, 0.0, 0.0]
    phi, _ = c.step(q, np.zeros(3), chiee, np.zeros(3))
    assert np.all(np.isfinite(phi))
    before = c.state
    # a measurement the magnitude gates would refuse, straight into the core: either the tick is
    # refused and the state is unchanged, or its command is finite (saturated) and the state stays
    # finite within the bound
    try:
        phi, _ = c.step([1e308, 0.0, 0.3], np.zeros(3), [1e308, 0.1, 0.0], np.zeros(3))
    except ValueError as exc:
        assert "non-finite" in str(exc)
        np.testing.assert_array_equal(c.state.e_int, before.e_int)
    else:
        assert np.all(np.isfinite(phi))
    assert np.all(np.isfinite(c.state.e_int)) and np.all(
        np.abs(c.state.e_int) <= control.INTEGRAL_LIMIT
    )
    c._state[:] = [
        1e300,
        -1e300,
        0.0,
        0.0,  # whatever put it there, the next tick brings it back into bounds
    ]
    phi, info = c.step(q, np.zeros(3), chiee, np.zeros(3))
    assert np.all(np.isfinite(phi)) and np.all(np.abs(c.state.e_int) <= control.INTEGRAL_LIMIT)
    np.testing.assert_array_equal(info.e_int, c.state.e_int)


def test_controller_refuses_negative_optimality_error_and_absurd_q(params) -> None:
    c = Controller(ControllerKind.PSATID, params)
    for label in ("optimality error -1", "q_des 1e308", "kappa 1e3"):
        with pytest.raises(ValueError):
            c.set_setpoint(POISON[label][0])
    assert c.setpoint is None


def test_refusals_carry_their_reason(params) -> None:
    """State and setpoint refusals carry a typed reason (counted as is) with the text shown."""
    bounds = q_bounds(params)
    q, chiee, chiee_dot = [-1.1, 0.008, 0.3], [0.005, 0.128, -0.07], [0.01, 0.0, 0.1]
    refusal = state_problem(bounds, q, [1e6, 0.0, 0.0], chiee, chiee_dot, True)
    assert refusal.reason is StateRejection.IMPLAUSIBLE_RATES
    assert refusal.startswith("implausible rates: ")
    setpoint = Setpoint(np.zeros(3), np.zeros(3), np.zeros(2), -1.0)
    refusal = SetpointValidator(params).problem(setpoint)
    assert refusal.reason is SetpointRejection.OPTIMALITY
    assert refusal == "optimality error outside [0, 0.001]: -1.0"

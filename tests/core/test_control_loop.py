"""The supervised controller tick (hsa_core.controller.control_loop) on a stand-in law: setpoint
activation, track -> hold -> stale -> track, E-stop, refused steps and states, counters; expected
values from docs/nodes/hsa_controller_node.md."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from hsa_core.controller.control import ControllerState
from hsa_core.controller.control_loop import (
    SETPOINT_CHECKS,
    SETPOINT_INTAKE,
    Activation,
    ControlLoop,
)
from hsa_core.controller.supervision import Action, Mode, Supervisor, SupervisorConfig
from hsa_core.controller.validation import SetpointRejection
from hsa_core.model.params import load_params
from hsa_core.refusal import Refusal, StateRejection
from hsa_core.task.planning import Setpoint

MS = 1_000_000  # ns
Q, CHIEE, ZERO = np.zeros(3), np.array([0.0, 0.12, 0.0]), np.zeros(3)
SP_A, SP_B = (Setpoint(CHIEE, Q, np.full(2, v), 0.0) for v in (1.0, 2.0))


class FakeLaw:
    """Stands in for hsa_core.controller.control.Controller: the n-th step commands φ = [n, n] and
    leaves e_int = [n, n]."""

    def __init__(self) -> None:
        self.params, self.dt = load_params("fpu"), 0.025
        self.n, self.active, self.refuse_step = 0, [], False

    def set_setpoint(self, setpoint: Setpoint) -> None:
        if not np.all(np.isfinite(setpoint.phi_ss)):
            raise ValueError("setpoint contains non-finite values")
        self.active.append(setpoint)

    def step(self, q, q_dot, chiee, chiee_dot):
        if self.refuse_step:
            raise ValueError("non-finite command or integrator state: tick refused")
        self.n += 1
        return np.full(2, float(self.n)), SimpleNamespace(saturated=self.n == 1)

    def reset(self) -> None:
        self.n = 0

    @property
    def state(self) -> ControllerState:
        return ControllerState(np.full(2, float(self.n)), np.zeros(2))


def _loop(driver_timeout: float = 0.0, check=None) -> tuple[FakeLaw, ControlLoop]:
    """A loop with the node's default bounds (0.1 s stale, 0.25 s hold) around a FakeLaw."""
    law = FakeLaw()
    return law, ControlLoop(
        law, Supervisor(SupervisorConfig(0.1, 0.25, driver_timeout)), check=check
    )


def _state(loop: ControlLoop, stamp: int, now: int | None = None) -> None:
    assert loop.state(stamp, stamp if now is None else now, Q, ZERO, CHIEE, ZERO) is None


def _tracking_at(t: int) -> tuple[FakeLaw, ControlLoop]:
    """A loop whose setpoint A is active and that tracked once at t on a state stamped t."""
    law, loop = _loop()
    loop.receive_setpoint(t - MS, SP_A, "a")
    _state(loop, t)
    assert loop.tick(t).sent is Action.STEP
    return law, loop


def test_a_setpoint_is_active_from_the_first_tick_after_its_stamp() -> None:
    law, loop = _loop()
    loop.receive_setpoint(100 * MS, SP_A, "a")
    # a tick at the very instant of the stamp still uses the previous (none)
    first = loop.tick(100 * MS)
    assert (
        first.activated == ()
        and first.mode is Mode.WAITING_FOR_SETPOINT
        and loop.active_tag is None
    )
    second = loop.tick(125 * MS)
    assert (
        second.activated == (Activation("a", None),)
        and loop.active_tag == "a"
        and law.active == [SP_A]
    )
    assert second.mode is Mode.WAITING_FOR_STATE
    loop.receive_setpoint(130 * MS, SP_B, "b")
    loop.receive_setpoint(140 * MS, SP_A, "a2")
    loop.receive_setpoint(150 * MS, SP_B, "b2")  # stamped at the tick: waits for the next one
    assert [a.tag for a in loop.tick(150 * MS).activated] == [
        "a2"
    ] and loop.active_tag == "a2"  # the newest due wins
    assert [a.tag for a in loop.tick(175 * MS).activated] == ["b2"] and loop.active_tag == "b2"
    c = loop.counters
    assert (c.received_setpoints, c.setpoints, c.superseded_setpoints, c.rejected_setpoints) == (
        4,
        3,
        1,
        0,
    )


def test_a_refused_setpoint_leaves_the_previous_one_active() -> None:
    refusal = Refusal.of(SetpointRejection.NOT_EQUILIBRIUM, "0.02")
    law, loop = _loop(check=lambda sp: refusal if sp is SP_B else None)
    loop.receive_setpoint(0, SP_A, "a")
    loop.receive_setpoint(0, SP_B, "b")
    loop.receive_setpoint(0, Setpoint(CHIEE, Q, np.full(2, math.nan), 0.0), "nan")
    activated = loop.tick(25 * MS).activated
    assert [(a.tag, a.problem is None) for a in activated] == [
        ("a", True),
        ("b", False),
        ("nan", False),
    ]
    assert loop.active_tag == "a" and law.active == [SP_A]
    assert loop.counters.rejected_setpoints == 2 and loop.counters.setpoints == 1
    rejected = loop.rejections.setpoints
    assert dict(rejected) == {SetpointRejection.NOT_EQUILIBRIUM: 1, SetpointRejection.LAW: 1}
    assert all(type(reason) is SetpointRejection for reason in rejected)  # typed, not parsed
    assert loop.rejections.last_setpoint == "setpoint contains non-finite values"  # the law's words


def test_a_setpoint_flood_costs_the_tick_a_bounded_number_of_checks_and_the_newest_wins() -> None:
    checked = []
    law, loop = _loop(check=lambda sp: checked.append(sp) or None)
    flood = [Setpoint(CHIEE, Q, np.full(2, 1.0 + k * 1e-6), 0.0) for k in range(10_000)]
    for k, sp in enumerate(flood):  # 10 000 valid setpoints between two ticks
        loop.receive_setpoint(k, sp, k)
    tick = loop.tick(10_000)
    assert tick.activated == (Activation(9_999, None),) and loop.active_tag == 9_999
    assert checked == [flood[-1]] and law.active == [flood[-1]], (
        "one check and one activation, whatever the load"
    )
    c = loop.counters
    assert (c.received_setpoints, c.setpoints, c.superseded_setpoints, c.rejected_setpoints) == (
        10_000,
        1,
        9_999,
        0,
    )
    assert loop.pending_setpoints == 0
    for k in range(100):  # stamped in the future: kept, but never more than the intake holds
        loop.receive_setpoint(10**12 + k, flood[k], f"future {k}")
    assert (
        loop.pending_setpoints == SETPOINT_INTAKE
        and c.superseded_setpoints == 9_999 + 100 - SETPOINT_INTAKE
    )
    loop.drop_setpoints(7)  # dropped undecoded by the caller: received and superseded
    assert (c.received_setpoints, c.superseded_setpoints) == (
        10_107,
        9_999 + 100 - SETPOINT_INTAKE + 7,
    )


def test_a_refused_newest_setpoint_leaves_the_newest_valid_one_active_within_the_check_budget() -> (
    None
):
    nan = Setpoint(CHIEE, Q, np.full(2, math.nan), 0.0)
    law, loop = _loop()
    loop.receive_setpoint(0, SP_A, "a")
    loop.receive_setpoint(0, SP_B, "b")  # valid: the previous one to keep
    for k in range(SETPOINT_CHECKS - 1):
        loop.receive_setpoint(0, nan, f"nan {k}")
    activated = loop.tick(25 * MS).activated
    assert [a.tag for a in activated] == ["b", *(f"nan {k}" for k in range(SETPOINT_CHECKS - 1))]
    assert (
        loop.active_tag == "b" and law.active == [SP_B] and loop.counters.superseded_setpoints == 1
    )
    assert loop.counters.rejected_setpoints == SETPOINT_CHECKS - 1
    for k in range(
        SETPOINT_CHECKS + 3
    ):  # more refused ones than the budget: the valid one before is not reached
        loop.receive_setpoint(30 * MS, SP_A if k == 0 else nan, k)
    activated = loop.tick(50 * MS).activated
    assert (
        len(activated) == SETPOINT_CHECKS
        and all(a.problem for a in activated)
        and loop.active_tag == "b"
    )
    assert (
        loop.counters.superseded_setpoints == 1 + 3
        and loop.counters.rejected_setpoints == 2 * SETPOINT_CHECKS - 1
    )


def test_an_unreadable_setpoint_is_counted_as_refused_and_the_active_one_stays() -> None:
    law, loop = _loop()
    loop.receive_setpoint(0, SP_A, "a")
    loop.tick(25 * MS)
    loop.refuse_setpoint("undecodable: Fast CDR exception")
    loop.tick(50 * MS)
    assert loop.active_tag == "a" and law.active == [SP_A]
    assert (
        loop.counters.received_setpoints,
        loop.counters.setpoints,
        loop.counters.rejected_setpoints,
    ) == (2, 1, 1)
    assert loop.rejections.setpoints[
        "undecodable"
    ] == 1 and loop.rejections.last_setpoint.startswith("undecodable")


def test_track_then_hold_then_stale_then_track_again() -> None:
    t = 1000 * MS
    law, loop = _tracking_at(t)
    for k in range(1, 5):  # state age 25..100 ms <= stale_timeout: steps
        assert loop.tick(t + k * 25 * MS).sent is Action.STEP
    assert law.n == 5
    held = [loop.tick(t + k * 25 * MS) for k in range(5, 11)]  # age 125..250 ms: the hold, 6 ticks
    assert all(h.mode is Mode.HOLD and h.sent is Action.HOLD for h in held)
    assert all(
        np.array_equal(h.command.phi, [5.0, 5.0]) and h.command.source_stamp_ns == t for h in held
    )
    entry = held[0].transition
    assert (entry.old, entry.new) == (Mode.TRACKING, Mode.HOLD) and math.isnan(entry.outage_s)
    assert all(h.transition is None for h in held[1:])
    # not stepped: integrators frozen
    assert law.n == 5 and np.array_equal(law.state.e_int, [5.0, 5.0])
    stale = loop.tick(t + 275 * MS)  # age 275 ms > hold_timeout: nothing sent
    assert (stale.mode, stale.sent, stale.command) == (Mode.STALE, Action.NONE, None) and law.n == 5
    _state(loop, t + 290 * MS)
    back = loop.tick(t + 300 * MS)
    assert back.sent is Action.STEP and back.command.source_stamp_ns == t + 290 * MS and law.n == 6
    assert back.transition.new is Mode.TRACKING
    # last tracking tick t + 100 ms, back at t + 300 ms
    assert back.transition.outage_s == pytest.approx(0.2)
    c = loop.counters
    assert (c.stale_events, c.held_ticks, c.stale_stops, c.saturated) == (1, 6, 1, 1)
    assert loop.last_outage_s == pytest.approx(0.2)


def test_estop_resets_the_integrators_and_drops_the_held_command() -> None:
    t = 1000 * MS
    law, loop = _tracking_at(t)
    assert loop.set_estop(True) is True and loop.set_estop(True) is False
    assert law.n == 0 and loop.counters.estop_events == 1
    stopped = loop.tick(t + 25 * MS)
    assert (stopped.mode, stopped.sent) == (Mode.ESTOP, Action.NONE)
    assert loop.set_estop(False) is True
    after = loop.tick(t + 150 * MS)  # state 150 ms old: the pre-stop command is never re-sent
    assert (after.mode, after.sent) == (Mode.STALE, Action.NONE)


def test_a_refused_step_sends_nothing_keeps_the_mode_and_leaves_nothing_to_hold() -> None:
    law, loop = _loop()
    loop.receive_setpoint(0, SP_A, "a")
    _state(loop, 20 * MS)
    law.refuse_step = True
    refused = loop.tick(25 * MS)
    assert refused.sent is Action.NONE and refused.refused.startswith("non-finite command")
    # the mode before the tick
    assert refused.mode is Mode.WAITING_FOR_SETPOINT and refused.transition is None
    assert loop.counters.refused_ticks == 1
    stale = loop.tick(150 * MS)  # age 130 ms, but no command was ever sent: nothing to hold
    assert (stale.mode, stale.sent) == (Mode.STALE, Action.NONE)


def test_states_are_checked_before_they_can_be_used() -> None:
    _, loop = _loop()
    loop.receive_setpoint(0, SP_A, "a")
    assert loop.state(10 * MS, 10 * MS, Q, ZERO, np.array([math.nan, 0.1, 0.0]), ZERO) is not None
    assert loop.state(10 * MS, 10 * MS, Q, ZERO, np.array([5.0, 0.1, 0.0]), ZERO) is not None
    # not refused, not used
    assert loop.state(10 * MS, 10 * MS, Q, ZERO, CHIEE, ZERO, velocity_valid=False) is None
    assert loop.tick(25 * MS).mode is Mode.WAITING_FOR_STATE
    _state(loop, 30 * MS)
    assert loop.state(30 * MS, 31 * MS, Q, ZERO, CHIEE, ZERO) == "older than the newest state"
    assert dict(loop.rejections.states) == {
        "non-finite pose or configuration": 1,
        "implausible pose or configuration": 1,
        "older than the newest state": 1,
    }
    assert loop.rejections.last_state == "older than the newest state"
    assert all(type(reason) is StateRejection for reason in loop.rejections.states)  # not parsed
    assert loop.tick(50 * MS).sent is Action.STEP


def test_driver_loss_is_entered_once_and_counted() -> None:
    law, loop = _loop(driver_timeout=0.25)
    loop.receive_setpoint(0, SP_A, "a")
    loop.heartbeat(0)
    for k in range(1, 16):
        _state(loop, k * 25 * MS)
        tick = loop.tick(k * 25 * MS)
        assert tick.mode is (Mode.TRACKING if k * 25 <= 250 else Mode.DRIVER_LOST), k
    assert law.n == 10 and loop.counters.driver_lost_events == 1


def test_driver_torque_off_leaves_tracking_freezes_the_integrators_and_is_counted() -> None:
    law, loop = _loop(driver_timeout=0.25)
    loop.receive_setpoint(0, SP_A, "a")
    modes = []
    for k in range(1, 13):
        now = k * 25 * MS
        loop.heartbeat(now)
        _state(loop, now)
        if k in (4, 8):
            assert loop.driver_torque(k == 8) is True
        tick = loop.tick(now)
        modes.append(tick.mode)
        assert (tick.sent is Action.NONE) == (tick.mode is Mode.TORQUE_OFF)
    assert modes == [Mode.TRACKING] * 3 + [Mode.TORQUE_OFF] * 4 + [Mode.TRACKING] * 5
    # 4 ticks without a step: integrators frozen
    assert law.n == 8 and loop.counters.torque_off_events == 1


def test_deadline_misses_and_the_period_tick_rate() -> None:
    _, loop = _loop()
    for t in (25, 50, 75, 125, 150):  # 125 comes 50 ms after 75: more than 1.5 periods
        loop.tick(t * MS)
    assert (loop.counters.ticks, loop.counters.deadline_misses) == (5, 1)
    period = loop.period(200 * MS)
    # 5 ticks in 0.2 s, no step
    assert period.rate_hz == pytest.approx(25.0) and period.compute_s == ()
    assert loop.period(300 * MS).rate_hz == 0.0

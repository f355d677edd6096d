"""Controller supervision state machine (hsa_core.controller.supervision): every mode transition,
with the time passed in."""

from __future__ import annotations

import pytest

from hsa_core.controller.supervision import Action, Mode, Supervisor, SupervisorConfig

MS = 1_000_000  # ns
STALE, HOLD, DRIVER = 100 * MS, 250 * MS, 250 * MS


def _supervisor(driver_timeout: float = 0.25, stamp_clock: bool = True) -> Supervisor:
    """A supervisor with the node's default bounds."""
    return Supervisor(SupervisorConfig(0.1, 0.25, driver_timeout, stamp_clock))


def _tracking(t: int = 1000 * MS) -> Supervisor:
    """A supervisor that tracks at time t: setpoint, heartbeat and a state stamped t."""
    s = _supervisor()
    s.setpoint_accepted()
    s.driver_heartbeat(t)
    assert s.state(t, t) is None
    assert s.tick(t).mode is Mode.TRACKING
    return s


def test_start_up_waits_for_setpoint_then_driver_then_state() -> None:
    s = _supervisor()
    t = 1000 * MS
    assert (s.tick(t).mode, s.tick(t).action) == (Mode.WAITING_FOR_SETPOINT, Action.NONE)
    s.setpoint_accepted()
    assert (s.tick(t).mode, s.tick(t).action) == (Mode.WAITING_FOR_DRIVER, Action.NONE)
    s.driver_heartbeat(t)
    assert (s.tick(t).mode, s.tick(t).action) == (Mode.WAITING_FOR_STATE, Action.NONE)
    assert s.state(t - 5 * MS, t) is None
    decision = s.tick(t)
    assert (decision.mode, decision.action) == (Mode.TRACKING, Action.STEP)
    assert decision.age_s == pytest.approx(0.005)


def test_no_driver_in_the_graph_tracks_without_heartbeats() -> None:
    s = _supervisor(driver_timeout=0.0)
    s.setpoint_accepted()
    assert s.state(0, 0) is None
    assert s.tick(10 * MS).mode is Mode.TRACKING


def test_age_by_stamp_tracks_holds_then_stops_and_resumes() -> None:
    t = 1000 * MS
    s = _tracking(t)
    for dt, mode, action in (
        (STALE, Mode.TRACKING, Action.STEP),
        (STALE + 1, Mode.HOLD, Action.HOLD),
        (HOLD, Mode.HOLD, Action.HOLD),
        (HOLD + 1, Mode.STALE, Action.NONE),
    ):
        s.driver_heartbeat(t + dt)
        decision = s.tick(t + dt)
        assert (decision.mode, decision.action) == (mode, action), dt
    s.driver_heartbeat(t + 2000 * MS)
    assert s.state(t + 1990 * MS, t + 2000 * MS) is None
    assert s.tick(t + 2000 * MS).mode is Mode.TRACKING


def test_a_state_with_an_old_stamp_is_stale_even_if_it_just_arrived() -> None:
    t = 1000 * MS
    s = _tracking(t)
    s.driver_heartbeat(t + 2000 * MS)
    # newer than the newest, but stamped ~2 s ago
    assert s.state(t + 10 * MS, t + 2000 * MS) is None
    decision = s.tick(t + 2000 * MS)
    assert decision.action is not Action.STEP and decision.age_s == pytest.approx(1.99)


def test_arrival_age_when_stamps_are_not_on_this_clock() -> None:
    s = _supervisor(driver_timeout=0.0, stamp_clock=False)
    s.setpoint_accepted()
    assert s.state(5 * MS, 100_000 * MS) is None  # a recorded stamp, 100 s in the past
    assert s.tick(100_050 * MS).mode is Mode.TRACKING
    assert s.tick(100_000 * MS + STALE + 1).mode is Mode.HOLD


def test_hold_needs_a_previous_command() -> None:
    s = _supervisor()
    s.setpoint_accepted()
    s.driver_heartbeat(1000 * MS)
    assert s.state(850 * MS, 1000 * MS) is None  # first state already stale: nothing to hold
    assert (s.tick(1000 * MS).mode, s.tick(1000 * MS).action) == (Mode.STALE, Action.NONE)


def test_states_are_ordered_by_stamp_and_future_stamps_refused() -> None:
    t = 1000 * MS
    s = _tracking(t)
    assert s.state(t, t + 5 * MS) == "older than the newest state"
    assert s.state(t - MS, t + 5 * MS) == "older than the newest state"
    assert s.state(t + 5 * MS + STALE + 1, t + 5 * MS) == "stamped in the future"
    assert s.state(t + 5 * MS, t + 5 * MS) is None  # the genuine stream goes on
    assert s.age_s(t + 5 * MS) == 0.0


def test_driver_lost_freezes_then_resumes() -> None:
    t = 1000 * MS
    s = _tracking(t)
    for k in range(1, 20):
        now = t + k * 25 * MS
        assert s.state(now, now) is None
        decision = s.tick(now)
        expected = Mode.TRACKING if k * 25 * MS <= DRIVER else Mode.DRIVER_LOST
        assert decision.mode is expected, k
        if expected is Mode.DRIVER_LOST:
            assert decision.action is Action.NONE and decision.driver_silence_s > 0.25
    s.driver_heartbeat(t + 500 * MS)
    assert s.tick(t + 500 * MS).mode is Mode.TRACKING


def test_driver_torque_off_sends_nothing_until_it_is_on_again() -> None:
    t = 1000 * MS
    s = _tracking(t)
    assert s.driver_torque(True) is False  # no report yet counts as on: nothing changes
    assert s.driver_torque(False) is True and s.driver_torque(False) is False
    for k in range(
        1, 5
    ):  # heartbeats and fresh states keep coming: the driver is alive, its servos powerless
        now = t + k * 25 * MS
        s.driver_heartbeat(now)
        assert s.state(now, now) is None
        assert (s.tick(now).mode, s.tick(now).action) == (Mode.TORQUE_OFF, Action.NONE)
    assert s.tick(t + 400 * MS).mode is Mode.DRIVER_LOST  # silence outranks the torque report
    s.driver_heartbeat(t + 400 * MS)
    assert s.driver_torque(True) is True
    # state 300 ms old: nothing held across the torque-off
    assert s.tick(t + 400 * MS).mode is Mode.STALE
    assert s.state(t + 400 * MS, t + 400 * MS) is None
    assert s.tick(t + 400 * MS).mode is Mode.TRACKING
    s.driver_torque(False)
    assert s.set_estop(True) and s.tick(t + 400 * MS).mode is Mode.ESTOP  # the E-stop outranks it


def test_estop_has_priority_and_drops_the_hold() -> None:
    t = 1000 * MS
    s = _tracking(t)
    assert s.set_estop(True) is True
    assert s.set_estop(True) is False  # entered once
    assert (s.tick(t).mode, s.tick(t).action) == (Mode.ESTOP, Action.NONE)
    assert s.set_estop(False) is False
    s.driver_heartbeat(t + 150 * MS)
    # stale after the E-stop: no command from before it is re-sent
    assert s.tick(t + 150 * MS).mode is Mode.STALE
    assert s.state(t + 150 * MS, t + 150 * MS) is None
    assert s.tick(t + 150 * MS).mode is Mode.TRACKING


@pytest.mark.parametrize(
    "stale, hold, driver", [(0.0, 0.25, 0.25), (0.3, 0.25, 0.25), (0.1, 0.25, -1.0)]
)
def test_inconsistent_bounds_are_refused(stale: float, hold: float, driver: float) -> None:
    with pytest.raises(ValueError):
        SupervisorConfig(stale, hold, driver)

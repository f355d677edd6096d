"""Lockstep playback decisions (hsa_core.sim.playback): start, instants from log times and timer
dues, settle before the clock moves, finish before the next message, /clock resend, wall-clock
timeouts."""

from __future__ import annotations

from hsa_core.sim.lockstep import DISCOVERY_SETTLE, Barrier, Report
from hsa_core.sim.playback import Action, LockstepPlayback

MS = 1_000_000
T0 = 1_760_000_000 * 10**9  # a real bag's log times: ns since the epoch


def kinematics(
    clock_ns: int = 0, taken: int = 0, published: int = 0, due: int | None = None
) -> Report:
    """The one participant: takes /ee, publishes /state (taken by nobody), maybe has a timer due."""
    return Report(
        "/kin",
        clock_ns,
        next_due_ns=due,
        published={"/state": published},
        matched={"/state": 0},
        taken={"/ee": taken},
    )


def started(
    timeout: float = 5.0, *others: Report, matched: int = 1
) -> tuple[Barrier, LockstepPlayback]:
    """A playback whose start condition holds and has settled (the participant and ``others``
    reported, the player's /ee matched ``matched`` times since DISCOVERY_SETTLE s before 0)."""
    barrier = Barrier(["/kin"])
    barrier.own = {"/ee": 0}
    for r in (kinematics(), *others):
        barrier.report(r)
    playback = LockstepPlayback(barrier, timeout=timeout)
    assert playback.step(T0, {"/ee": matched}, now=-DISCOVERY_SETTLE).action == "wait"
    return barrier, playback


def test_time_starts_when_the_participants_are_ready_and_take_the_players_topics() -> None:
    barrier = Barrier(["/kin"])
    playback = LockstepPlayback(barrier, timeout=5.0)
    step = playback.step(T0, {"/ee": 0}, now=0.0)
    assert step.action == "wait" and "waiting for participants ['/kin']" in step.reason
    barrier.report(kinematics())
    step = playback.step(T0, {"/ee": 0}, now=0.1)
    assert (
        step.action == "wait"
        and step.reason == "simulator: '/ee' matched 0 of 1 participant subscriptions"
    )
    step = playback.step(T0, {"/ee": 1}, now=0.25)
    assert step.action == "wait" and step.reason.startswith("discovery complete 0.000 s ago")
    assert playback.step(T0, {"/ee": 1}, now=0.25 + DISCOVERY_SETTLE / 2).action == "wait"
    step = playback.step(T0, {"/ee": 1}, now=0.25 + DISCOVERY_SETTLE)
    assert (step.action, step.t_ns) == (
        "clock",
        T0,
    ) and barrier.started  # the first instant: the first log time


def test_a_message_is_published_only_after_its_instant_is_finished() -> None:
    barrier, playback = started()
    barrier.report(kinematics(due=T0))  # a timer due at the first instant
    assert playback.step(T0, {"/ee": 1}, now=0.0).action == "clock"
    step = playback.step(T0, {"/ee": 1}, now=0.001)
    assert step.action == "wait" and step.reason == f"timers due at {T0} ns not yet run by ['/kin']"
    barrier.report(kinematics(clock_ns=T0, due=T0 + 25 * MS))  # it ran
    assert playback.step(T0, {"/ee": 1}, now=0.002).action == "publish"
    barrier.own["/ee"] = 1
    # a second message of the same log time
    assert playback.step(T0, {"/ee": 1}, now=0.003).action == "publish"


def test_the_clock_moves_only_when_every_published_message_was_taken() -> None:
    barrier, playback = started()
    playback.step(T0, {"/ee": 1}, now=0.0)
    barrier.report(kinematics(clock_ns=T0))
    assert playback.step(T0, {"/ee": 1}, now=0.0).action == "publish"
    barrier.own["/ee"] = 1
    step = playback.step(T0 + 5 * MS, {"/ee": 1}, now=0.01)
    assert step.action == "wait" and "has taken 0 of 1 messages on '/ee'" in step.reason
    barrier.report(kinematics(clock_ns=T0, taken=1, published=1))
    step = playback.step(T0 + 5 * MS, {"/ee": 1}, now=0.02)
    assert (step.action, step.t_ns) == ("clock", T0 + 5 * MS)


def test_a_timer_due_before_the_next_message_gets_its_own_instant() -> None:
    barrier, playback = started()
    playback.step(T0, {"/ee": 1}, now=0.0)
    barrier.report(kinematics(clock_ns=T0, due=T0 + 25 * MS))
    step = playback.step(T0 + 40 * MS, {"/ee": 1}, now=0.0)
    assert (step.action, step.t_ns) == (
        "clock",
        T0 + 25 * MS,  # the timer's instant, not the message's
    )
    step = playback.step(T0 + 40 * MS, {"/ee": 1}, now=0.01)
    assert step.action == "wait" and "timers due" in step.reason
    # the timer ran at its instant
    barrier.report(kinematics(clock_ns=T0 + 25 * MS, due=T0 + 50 * MS))
    step = playback.step(T0 + 40 * MS, {"/ee": 1}, now=0.0)
    assert (step.action, step.t_ns) == (
        "clock",
        T0 + 40 * MS,  # the message, before the next due (50 ms)
    )


def test_with_a_recorder_the_lead_goes_with_clock_where_a_timer_is_due() -> None:
    """A timer's messages at an instant may reach the recorder before /clock: it gets the instant
    with what precedes it (the lead), /clock follows at once, and the instant waits for the
    recorder's clock."""
    barrier, playback = started(
        5.0, Report("/rec", 0, taken={"/ee": 0}, clock_acks=True), matched=2
    )
    playback.step(T0, {"/ee": 2}, now=0.0)
    barrier.report(Report("/rec", T0, taken={"/ee": 1}, clock_acks=True))
    barrier.report(kinematics(clock_ns=T0, due=T0 + 25 * MS))
    step = playback.step(T0 + 40 * MS, {"/ee": 2}, now=0.0)
    assert (step.action, step.t_ns) == ("lead", T0 + 25 * MS)
    assert barrier.leads() == {"/rec": {"/ee": 1}}
    step = playback.step(T0 + 40 * MS, {"/ee": 2}, now=0.0)
    assert (step.action, step.t_ns, step.reason) == ("clock", T0 + 25 * MS, "")
    barrier.report(kinematics(clock_ns=T0 + 25 * MS, due=T0 + 50 * MS))
    step = playback.step(T0 + 40 * MS, {"/ee": 2}, now=0.1)
    assert (step.action, step.reason) == (
        "clock",  # sent again: it is best effort
        f"clock of ['/rec'] not yet at {T0 + 25 * MS} ns",
    )
    barrier.report(Report("/rec", T0 + 25 * MS, taken={"/ee": 1}, clock_acks=True))
    step = playback.step(T0 + 40 * MS, {"/ee": 2}, now=0.3)
    assert (step.action, step.t_ns) == (
        "clock",
        T0 + 40 * MS,  # no timer due: the player's messages wait anyway
    )


def test_timer_dues_before_the_first_message_are_not_stepped_through() -> None:
    barrier = Barrier(["/kin"])
    barrier.report(kinematics(due=25 * MS))  # a timer on the grid of simulated time 0
    playback = LockstepPlayback(barrier, timeout=5.0)
    assert playback.step(T0, {"/ee": 1}, now=-DISCOVERY_SETTLE).action == "wait"
    step = playback.step(T0, {"/ee": 1}, now=0.0)
    assert (step.action, step.t_ns) == ("clock", T0)  # one jump to the bag's first log time


def test_the_clock_is_sent_again_while_an_instant_waits() -> None:
    barrier, playback = started()
    barrier.report(kinematics(due=T0))
    playback.step(T0, {"/ee": 1}, now=0.0)
    assert playback.step(T0, {"/ee": 1}, now=0.03).action == "wait"
    step = playback.step(T0, {"/ee": 1}, now=0.06)
    assert (step.action, step.t_ns) == ("clock", T0) and "timers due" in step.reason
    assert playback.step(T0, {"/ee": 1}, now=0.08).action == "wait"


def test_done_only_when_the_last_message_was_taken() -> None:
    barrier, playback = started()
    playback.step(T0, {"/ee": 1}, now=0.0)
    barrier.report(kinematics(clock_ns=T0))
    playback.step(T0, {"/ee": 1}, now=0.0)
    barrier.own["/ee"] = 1
    assert playback.step(None, {"/ee": 1}, now=0.0).action == "wait"
    barrier.report(kinematics(clock_ns=T0, taken=1, published=1))
    assert playback.step(None, {"/ee": 1}, now=0.0).action == "done"


def test_an_instant_that_does_not_finish_in_time_fails_naming_the_holder() -> None:
    barrier, playback = started(timeout=2.0)
    barrier.report(kinematics(due=T0))  # a timer that never runs (the participant stalled)
    playback.step(T0, {"/ee": 1}, now=10.0)
    assert playback.step(T0, {"/ee": 1}, now=11.9).action in ("wait", "clock")
    step = playback.step(T0, {"/ee": 1}, now=12.1)
    assert step.action == "fail"
    assert step.reason.startswith(
        "lockstep barrier at t = 1760000000.000 s not finished after 2.1 s of wall time"
    )
    assert step.reason.endswith("timers due at 1760000000000000000 ns not yet run by ['/kin']")


def test_each_instant_has_its_own_timeout_and_the_start_ten_times_as_long() -> None:
    barrier = Barrier(["/kin"])
    playback = LockstepPlayback(barrier, timeout=1.0)
    assert playback.step(T0, {}, now=0.0).action == "wait"
    # start-up (nodes compiling) may take 10 timeouts
    assert playback.step(T0, {}, now=9.9).action == "wait"
    step = playback.step(T0, {}, now=10.1)
    assert step.action == "fail" and "before simulated time started" in step.reason
    barrier, playback = started(timeout=1.0)
    for k in range(5):  # five instants, each finished 0.9 s after its clock: no failure
        barrier.report(kinematics(clock_ns=T0 + (k - 1) * MS, due=T0 + k * MS))
        assert playback.step(T0 + k * MS, {"/ee": 1}, now=0.9 * k).action == "clock"
    # instant 4 waits 0.9 s: a resend
    assert playback.step(T0 + 5 * MS, {"/ee": 1}, now=4.5).action == "clock"
    assert playback.step(T0 + 5 * MS, {"/ee": 1}, now=4.7).action == "fail"  # its timer never runs


def test_every_step_carries_an_action_member() -> None:
    """The player dispatches on Action members, not strings: wait, clock, publish, done and fail."""
    barrier = Barrier(["/kin"])
    playback = LockstepPlayback(barrier, timeout=1.0)
    steps = [playback.step(T0, {"/ee": 1}, now=0.0)]  # the participant has not reported
    barrier.own = {"/ee": 0}
    barrier.report(kinematics())
    playback.step(T0, {"/ee": 1}, now=0.1)  # discovery settling
    steps.append(playback.step(T0, {"/ee": 1}, now=0.1 + DISCOVERY_SETTLE))
    barrier.report(kinematics(T0))
    steps.append(playback.step(T0, {"/ee": 1}, now=0.7))
    steps.append(playback.step(None, {"/ee": 1}, now=0.8))
    stuck = LockstepPlayback(Barrier(["/kin"]), timeout=1.0)
    stuck.step(T0, {}, now=0.0)
    steps.append(stuck.step(T0, {}, now=10.1))  # start-up may take 10 timeouts
    assert [type(step.action) for step in steps] == [Action] * 5
    assert [step.action for step in steps] == [
        Action.WAIT,
        Action.CLOCK,
        Action.PUBLISH,
        Action.DONE,
        Action.FAIL,
    ]

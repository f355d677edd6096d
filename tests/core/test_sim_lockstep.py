"""The simulator's lockstep decisions (hsa_core.sim.sim_lockstep): start, samples between instants
without /clock, a sync instant every 50 ms, /clock only at timer dues, finish waits for the bus,
resend, stop when a participant leaves, wall-clock timeouts."""

from __future__ import annotations

from hsa_core.sim.lockstep import DISCOVERY_SETTLE, Barrier, Report
from hsa_core.sim.sim_lockstep import BUS_BUSY, SimLockstep

MS = 1_000_000
MATCHED = {"/mocap": 1, "/clock": 1}  # the simulator's publishers: subscriptions matched


def controller(
    clock_ns: int = 0, taken: int = 0, due: int | None = None, leaving: bool = False
) -> Report:
    """The one participant: takes the simulator's /mocap samples, maybe has a timer due."""
    return Report(
        "/ctl",
        clock_ns,
        next_due_ns=due,
        leaving=leaving,
        taken={"/mocap": taken},
        heard={"/clock": 1},
    )


def started(timeout: float = 5.0) -> tuple[Barrier, SimLockstep]:
    """A coordinator past its start (the participant reported, every publisher matched)."""
    barrier = Barrier(["/ctl"])
    barrier.own = {"/mocap": 0}
    barrier.report(controller())
    sim = SimLockstep(barrier, timeout=timeout)
    assert step(sim, -DISCOVERY_SETTLE).action in ("wait", "clock")  # discovery settling
    assert step(sim, 0.0).action == "start"
    return barrier, sim


def step(
    sim: SimLockstep, now: float, world_ns: int = 0, sample_ns: int = 6 * MS, idle: bool = True
):
    """One decision with the bus ``idle`` and every publisher matched."""
    return sim.step(now, world_ns, sample_ns, lambda: idle, lambda: MATCHED)


def test_time_starts_when_the_participants_are_ready_and_clock_0_is_resent_meanwhile() -> None:
    barrier = Barrier(["/ctl"])
    sim = SimLockstep(barrier, timeout=5.0, resend=0.05)
    first = step(sim, 100.0)
    assert (first.action, first.t_ns) == (
        "clock",
        0,
    ) and "waiting for participants ['/ctl']" in first.reason
    assert step(sim, 100.01).action == "wait"  # resent at most every 50 ms
    assert step(sim, 100.07).action == "clock"
    barrier.report(controller())
    settling = step(sim, 100.25)
    assert settling.action == "clock" and settling.reason.startswith("discovery complete 0.000 s")
    assert step(sim, 100.25 + DISCOVERY_SETTLE / 2).action == "clock"
    assert step(sim, 100.25 + DISCOVERY_SETTLE).action == "start" and barrier.started


def test_samples_between_instants_are_run_without_clock_and_an_instant_comes_every_50_ms() -> None:
    barrier, sim = started()
    for t in range(0, 50, 5):  # no timer due: no /clock until 50 ms of simulated time have passed
        s = step(sim, 0.0, world_ns=max(t - 5, 0) * MS, sample_ns=t * MS)
        assert (s.action, s.t_ns) == ("run", t * MS)
    s = step(sim, 0.0, world_ns=45 * MS, sample_ns=50 * MS)
    assert (s.action, s.t_ns) == ("publish", 45 * MS)  # the runs' samples, before the instant
    s = step(sim, 0.0, world_ns=45 * MS, sample_ns=50 * MS)
    assert (s.action, s.t_ns) == (
        "instant",
        50 * MS,  # 50 ms of simulated time since the last instant
    )
    barrier.own["/mocap"] = 10
    s = step(sim, 0.1, world_ns=50 * MS, sample_ns=55 * MS)
    assert s.action == "wait" and "has taken 0 of 10 messages on '/mocap'" in s.reason
    barrier.report(controller(taken=10))
    assert step(sim, 0.2, world_ns=50 * MS, sample_ns=55 * MS).action == "run"


def test_at_a_due_timer_the_clock_moves_and_the_instant_ends_once_timers_ran_and_bus_idles() -> (
    None
):
    barrier, sim = started()
    barrier.report(controller(due=25 * MS))
    s = step(sim, 0.0, sample_ns=26 * MS)
    assert (s.action, s.t_ns) == ("instant", 25 * MS)
    s = step(sim, 0.0, world_ns=25 * MS, sample_ns=26 * MS)
    assert (s.action, s.t_ns, s.reason) == ("clock", 25 * MS, "")
    s = step(sim, 0.01, world_ns=25 * MS, sample_ns=26 * MS)
    assert s.action == "wait" and s.reason == f"timers due at {25 * MS} ns not yet run by ['/ctl']"
    barrier.report(controller(clock_ns=25 * MS, due=50 * MS))
    s = step(sim, 0.02, world_ns=25 * MS, sample_ns=26 * MS, idle=False)
    assert (s.action, s.reason) == ("wait", BUS_BUSY)
    s = step(sim, 0.06, world_ns=25 * MS, sample_ns=26 * MS, idle=False)
    assert (s.action, s.t_ns, s.reason) == (
        "clock",
        25 * MS,
        BUS_BUSY,  # resent: /clock is best effort
    )
    s = step(sim, 0.07, world_ns=25 * MS, sample_ns=26 * MS)
    assert (s.action, s.t_ns) == ("finish", 25 * MS)
    assert step(sim, 0.07, world_ns=25 * MS, sample_ns=26 * MS).action == "run"


def test_with_a_recorder_the_lead_goes_with_clock_and_the_instant_waits_for_its_clock() -> None:
    """A recorder logs in simulated time: it gets the instant with what precedes it (the lead), and
    /clock follows at once; the instant finishes only once the recorder reports its clock there."""
    barrier, sim = started()
    recorder = Report("/rec", 0, taken={"/mocap": 3}, clock_acks=True)
    barrier.report(recorder)
    barrier.report(controller(due=25 * MS))
    assert step(sim, 0.0, sample_ns=26 * MS).action == "instant"
    s = step(sim, 0.0, world_ns=25 * MS, sample_ns=26 * MS)
    assert (s.action, s.t_ns) == ("lead", 25 * MS)
    assert barrier.leads() == {"/rec": {"/mocap": 3}}
    s = step(sim, 0.0, world_ns=25 * MS, sample_ns=26 * MS)
    assert (s.action, s.t_ns, s.reason) == ("clock", 25 * MS, "")
    barrier.report(controller(clock_ns=25 * MS, due=50 * MS))
    s = step(sim, 0.01, world_ns=25 * MS, sample_ns=26 * MS)
    assert (s.action, s.reason) == ("wait", f"clock of ['/rec'] not yet at {25 * MS} ns")
    barrier.report(Report("/rec", 25 * MS, taken={"/mocap": 3}, clock_acks=True))
    assert step(sim, 0.02, world_ns=25 * MS, sample_ns=26 * MS).action == "finish"


def test_a_barrier_waiting_too_long_fails_naming_the_instant_and_the_start_has_its_own_limit() -> (
    None
):
    barrier, sim = started(timeout=2.0)
    barrier.report(controller(due=25 * MS))
    step(sim, 10.0, sample_ns=26 * MS)
    step(sim, 10.0, world_ns=25 * MS, sample_ns=26 * MS)  # /clock at 25 ms
    assert step(sim, 11.9, world_ns=25 * MS, sample_ns=26 * MS).action == "clock"  # resent
    assert step(sim, 11.9, world_ns=25 * MS, sample_ns=26 * MS).action == "wait"
    assert step(sim, 12.1, world_ns=25 * MS, sample_ns=26 * MS).action == "clock"
    s = step(sim, 12.1, world_ns=25 * MS, sample_ns=26 * MS)
    assert s.action == "fail" and s.reason.startswith(
        "lockstep barrier at t = 0.025 s not finished after 2.1 s of wall time: timers due at"
    )
    waiting = SimLockstep(Barrier(["/ctl"]), timeout=2.0, start_timeout=180.0)
    assert step(waiting, 1.0).action == "clock"
    assert [step(waiting, 180.9).action, step(waiting, 180.9).action] == ["clock", "wait"]
    assert [step(waiting, 181.1).action, step(waiting, 181.1).action] == ["clock", "fail"]


def test_simulated_time_stops_once_an_expected_participant_leaves() -> None:
    barrier, sim = started()
    barrier.report(controller(leaving=True))
    s = step(sim, 0.0)
    assert (s.action, s.reason) == ("stop", "/ctl left")
    assert step(sim, 0.1).action == "done"


def test_samples_run_to_are_published_before_simulated_time_stops() -> None:
    barrier, sim = started()
    assert step(sim, 0.0, sample_ns=5 * MS).action == "run"
    assert step(sim, 0.0, world_ns=5 * MS, sample_ns=10 * MS).action == "run"
    barrier.report(controller(leaving=True))
    s = step(sim, 0.0, world_ns=10 * MS, sample_ns=15 * MS)
    assert (s.action, s.t_ns) == ("publish", 10 * MS)
    assert step(sim, 0.0, world_ns=10 * MS, sample_ns=15 * MS).action == "stop"

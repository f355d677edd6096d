"""The lockstep barrier's decisions (hsa_core.sim.lockstep): start, settle, finish, late joiners,
leavers."""

from __future__ import annotations

from hsa_core.sim.lockstep import DISCOVERY_SETTLE, Barrier, LogTimes, Report, ReportPacing

MS = 1_000_000


def graph(**changes: Report) -> Barrier:
    """A three-node pipeline at rest: bridge → kinematics → controller, the simulator publishing
    poses."""
    reports = {
        "/bridge": Report(
            "/bridge", 0, published={"/ee": 0}, matched={"/ee": 1}, taken={"/pose": 0}
        ),
        "/kin": Report("/kin", 0, published={"/state": 0}, matched={"/state": 1}, taken={"/ee": 0}),
        "/ctrl": Report("/ctrl", 0, next_due_ns=25 * MS, taken={"/state": 0}),
    }
    reports.update(changes)
    barrier = Barrier(["/bridge", "/kin", "/ctrl"])
    barrier.own = {"/pose": 0}
    for r in reports.values():
        barrier.report(r)
    return barrier


def test_time_starts_only_when_every_expected_participant_is_ready_and_matched() -> None:
    barrier = Barrier(["/bridge", "/kin"])
    barrier.report(Report("/bridge", 0, published={"/ee": 0}, matched={"/ee": 0}))
    assert "waiting for participants ['/kin']" in barrier.discovery_problem()
    barrier.report(Report("/kin", 0, ready=False, taken={"/ee": 0}))
    assert "not ready" in barrier.discovery_problem()
    barrier.report(Report("/kin", 0, taken={"/ee": 0}))
    assert "'/ee' matched 0 of 1" in barrier.discovery_problem()
    barrier.report(Report("/bridge", 0, published={"/ee": 0}, matched={"/ee": 1}))
    assert barrier.discovery_problem() is None


def test_time_starts_only_when_every_subscription_knows_every_publisher() -> None:
    """DDS matches the ends separately: a reader that does not know a writer yet drops what it
    sends."""
    barrier = Barrier(["/bridge", "/kin"])
    barrier.report(
        Report("/bridge", 0, published={"/ee": 0}, matched={"/ee": 1}, heard={"/clock": 1})
    )
    # the writer knows the reader
    barrier.report(Report("/kin", 0, taken={"/ee": 0}, heard={"/ee": 0, "/clock": 1}))
    assert barrier.discovery_problem() == "/kin: subscription to '/ee' matched 0 of 1 publishers"
    barrier.report(Report("/kin", 0, taken={"/ee": 0}, heard={"/ee": 1, "/clock": 1}))
    assert barrier.discovery_problem() is None
    barrier.own_matched = {"/clock": 2}  # the simulator publishes /clock: it must be known too
    barrier.report(Report("/kin", 0, taken={"/ee": 0}, heard={"/ee": 1, "/clock": 0}))
    assert barrier.discovery_problem() == "/kin: subscription to '/clock' matched 0 of 1 publishers"


def test_time_starts_only_once_discovery_has_stayed_complete_and_unchanged() -> None:
    """Both ends matched is not enough: a recorder's best-effort subscription took none of the
    first samples sent 9 ms after it matched (a replay's start, on a loaded machine)."""
    barrier = Barrier(["/kin", "/rec"])
    barrier.own_matched = {"/pose": 1}
    barrier.report(Report("/kin", 0, heard={"/pose": 1}))
    barrier.report(Report("/rec", 0, ready=False))
    assert "not ready" in barrier.start_problem(10.0)
    barrier.report(Report("/rec", 0))
    assert barrier.start_problem(10.25) == "discovery complete 0.000 s ago, settling for 0.5 s"
    assert barrier.start_problem(10.5) == "discovery complete 0.250 s ago, settling for 0.5 s"
    # the recorder subscribes to /pose: counts change, the settling starts again
    barrier.own_matched = {"/pose": 2}
    barrier.report(Report("/rec", 0, heard={"/pose": 1}))
    assert barrier.start_problem(10.75).startswith("discovery complete 0.000 s ago")
    assert barrier.start_problem(10.75 + DISCOVERY_SETTLE / 2) is not None
    assert barrier.start_problem(10.75 + DISCOVERY_SETTLE) is None


def test_the_simulators_own_publishers_must_reach_every_participant_subscription() -> None:
    barrier = Barrier(["/kin", "/rec"])
    barrier.report(Report("/kin", 0, heard={"/pose": 1, "/clock": 1}))
    # takers: from taken as well
    barrier.report(Report("/rec", 0, taken={"/pose": 0}, heard={"/clock": 1}))
    barrier.own_matched = {
        "/pose": 1,
        "/clock": 2,
        "/diagnostics": 0,  # nobody subscribes to /diagnostics
    }
    assert (
        barrier.discovery_problem() == "simulator: '/pose' matched 1 of 2 participant subscriptions"
    )
    barrier.own_matched = {"/pose": 2, "/clock": 1, "/diagnostics": 0}
    assert (
        barrier.discovery_problem()
        == "simulator: '/clock' matched 1 of 2 participant subscriptions"
    )
    barrier.own_matched = {"/pose": 2, "/clock": 2, "/diagnostics": 0}
    assert barrier.discovery_problem() is None


def test_a_message_in_flight_holds_the_barrier_until_its_taker_reports() -> None:
    barrier = graph()
    assert barrier.settle_problem() is None
    barrier.own["/pose"] = 1  # the simulator published a pose
    assert "/bridge has taken 0 of 1 messages on '/pose'" == barrier.settle_problem()
    barrier.report(Report("/bridge", 0, published={"/ee": 1}, taken={"/pose": 1}))
    assert "/kin has taken 0 of 1" in barrier.settle_problem()  # the bridge passed it on
    barrier.report(Report("/kin", 0, published={"/state": 1}, taken={"/ee": 1}))
    assert "/ctrl has taken 0 of 1" in barrier.settle_problem()
    barrier.report(Report("/ctrl", 0, next_due_ns=25 * MS, taken={"/state": 1}))
    assert barrier.settle_problem() is None


def test_an_unanswered_service_request_holds_the_barrier() -> None:
    barrier = graph(**{"/ctrl": Report("/ctrl", 0, pending=1, taken={"/state": 0})})
    assert barrier.settle_problem() == "/ctrl awaits 1 service answer(s)"


def test_an_instant_is_finished_when_no_timer_due_is_left_and_all_is_settled() -> None:
    barrier = graph()
    assert barrier.next_due_ns() == 25 * MS
    assert barrier.finish_problem(24 * MS) is None  # nothing due yet
    assert barrier.finish_problem(25 * MS) == "timers due at 25000000 ns not yet run by ['/ctrl']"
    barrier.report(
        Report("/ctrl", 25 * MS, next_due_ns=50 * MS, published={"/cmd": 1}, taken={"/state": 0})
    )
    assert barrier.finish_problem(25 * MS) is None  # nobody takes /cmd among the participants
    barrier.report(Report("/drv", 25 * MS, taken={"/cmd": 0}))
    assert barrier.finish_problem(25 * MS) == "/drv has taken 0 of 1 messages on '/cmd'"
    barrier.report(Report("/drv", 25 * MS, taken={"/cmd": 1}))
    assert barrier.finish_problem(25 * MS) is None
    assert barrier.next_due_ns() == 50 * MS


def test_an_instant_waits_for_the_clock_of_a_clock_acking_participant_only() -> None:
    """A recorder (clock_acks) must have reported the instant's clock before the instant ends; other
    nodes need not report a clock move at all (their clocks stay behind in the barrier's view)."""
    barrier = graph(**{"/rec": Report("/rec", 0, taken={"/pose": 0}, clock_acks=True)})
    assert barrier.finish_problem(10 * MS) == "clock of ['/rec'] not yet at 10000000 ns"
    barrier.report(Report("/rec", 5 * MS, taken={"/pose": 0}, clock_acks=True))
    assert barrier.finish_problem(10 * MS) == "clock of ['/rec'] not yet at 10000000 ns"
    barrier.report(Report("/rec", 10 * MS, taken={"/pose": 0}, clock_acks=True))
    assert barrier.finish_problem(10 * MS) is None  # /bridge, /kin and /ctrl still report clock 0


def test_the_lead_clock_is_needed_only_with_a_clock_acking_participant_and_waits_for_it_alone() -> (
    None
):
    barrier = graph()
    # nobody logs in simulated time
    assert not barrier.needs_lead() and barrier.lead_problem(10 * MS) is None
    barrier.report(Report("/rec", 0, taken={"/pose": 0}, clock_acks=True))
    assert barrier.needs_lead()
    assert barrier.lead_problem(10 * MS) == "clock of ['/rec'] not yet at 10000000 ns"
    barrier.report(Report("/rec", 10 * MS, taken={"/pose": 0}, clock_acks=True))
    assert barrier.lead_problem(10 * MS) is None  # the other participants' clocks (0) do not matter


def test_a_late_joiner_is_settled_at_its_first_report_and_a_leaver_is_dropped() -> None:
    barrier = graph()
    barrier.start()
    barrier.own["/pose"] = 5
    barrier.report(Report("/bridge", 0, published={"/ee": 5}, taken={"/pose": 5}))
    barrier.report(Report("/kin", 0, published={"/state": 5}, taken={"/ee": 5}))
    barrier.report(Report("/ctrl", 0, taken={"/state": 5}))
    barrier.report(Report("/viewer", 0, taken={"/state": 0}))  # joins after 5 states went out
    assert barrier.settle_problem() is None
    barrier.report(Report("/kin", 0, published={"/state": 6}, taken={"/ee": 5}))
    barrier.report(Report("/ctrl", 0, taken={"/state": 6}))
    assert "/viewer has taken 5 of 6" in barrier.settle_problem()
    barrier.report(Report("/viewer", 0, leaving=True))
    assert barrier.settle_problem() is None


def test_an_expected_participant_leaving_marks_the_end_of_the_graph() -> None:
    barrier = graph()
    barrier.report(Report("/viewer", 0, leaving=True))
    assert barrier.left == []  # not expected: nothing ends
    barrier.report(Report("/kin", 0, leaving=True))
    assert barrier.left == ["/kin"] and "/kin" not in barrier.reports


def test_a_participant_reports_as_soon_as_no_callback_is_ready() -> None:
    """After each callback the executor polls (timeout 0) and reports when nothing is ready; then
    it waits a period at a time, reporting after each."""
    pacing = ReportPacing(period=0.02)
    assert pacing.timeout() == 0.0  # a fresh spin reports at its first poll
    for _ in range(3):  # a burst: every callback is followed by a poll
        pacing.ran()
        assert pacing.timeout() == 0.0
    pacing.timed_out()  # the report
    assert pacing.timeout() == 0.02  # then every period while idle
    pacing.timed_out()
    assert pacing.timeout() == 0.02
    pacing.ran()  # work again
    assert pacing.timeout() == 0.0


def test_log_times_give_each_message_the_instant_it_was_published_in() -> None:
    """A recorder at instant 25 ms takes messages 1-2 of /state (published before 50 ms) and, before
    the lead of 50 ms, a tick published at 50 ms (its /clock and lead not there yet): the lead's
    counts put the first two at the time they were taken and the tick at 50 ms."""
    written: list[tuple[str, int]] = []
    times = LogTimes()

    def take(name: str, topic: str, count: int, now_ns: int) -> None:
        times.take(topic, count, now_ns, lambda t: written.append((name, t)))

    take("state 1", "/state", 1, 25 * MS)
    take("state 2", "/state", 2, 25 * MS)
    take("tick", "/phi_cmd", 1, 25 * MS)  # raced ahead of its /clock
    assert written == []  # nothing is written before its instant is known
    times.lead(50 * MS, {"/state": 2, "/phi_cmd": 0})
    assert written == [("state 1", 25 * MS), ("state 2", 25 * MS)]
    take("state 3", "/state", 3, 50 * MS)  # between 50 and 75 ms
    times.lead(75 * MS, {"/state": 3, "/phi_cmd": 1})
    assert written[2:] == [("tick", 50 * MS), ("state 3", 50 * MS)]
    take("last", "/state", 4, 75 * MS)
    times.flush()
    assert written[4:] == [("last", 75 * MS)]


def test_a_message_held_over_several_leads_takes_the_latest_instant_it_follows() -> None:
    written: list[int] = []
    times = LogTimes()
    times.take("/diag", 1, 0, written.append)
    times.lead(25 * MS, {"/diag": 0})
    times.lead(50 * MS, {"/diag": 0})
    assert written == []
    times.lead(75 * MS, {"/diag": 1})  # published at 50 ms, before 75 ms
    assert written == [50 * MS]

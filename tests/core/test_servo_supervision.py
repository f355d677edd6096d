"""Tests of hsa_core.driver.servo_supervision.ServoSupervisor: the dynamixel_driver's torque,
watchdog, E-stop, link, hardware-error, start-up position and reboot decisions
(docs/nodes/hsa_dynamixel_driver.md).

Expected values come from the rules of that document: e.g. the sane range of motor 21 (sign +1,
neutral 1000) is 1000 + ⌊−(0.02 + 0.1) rad · 2048/π⌋ = 1000 − 79 = 921 ticks at its lower end.
"""

import math

import pytest

from hsa_core.driver.servo_supervision import (
    MULTI_TURN_NOTE,
    Alert,
    Answer,
    ServoSupervisor,
    Verdict,
    Watchdog,
    WatchdogEvent,
)
from hsa_core.model.actuation import MotorMap

IDS = (21, 22, 23, 24)
NEUTRAL = (1000, 3000, -500, 5000)
TOLERANCE = 0.1  # rad
MAP = MotorMap(NEUTRAL, IDS, phi_max=math.radians(200.0), margin=0.02)
AT_NEUTRAL = list(NEUTRAL)
TWISTED = [
    1000 + 200,
    3000 - 200,
    -500 + 200,
    5000 - 200,  # 200 ticks = 0.307 rad of twist on every motor
]


def describe(bits: int) -> str:
    """Stand-in for the bus's Hardware Error Status text."""
    return f"bits {bits}"


def configured(error_limit: int = 3) -> ServoSupervisor:
    """A supervisor after configure with the configured neutral NEUTRAL (not yet connected or
    active)."""
    sup = ServoSupervisor(IDS, error_limit, TOLERANCE, describe)
    sup.configured(neutral_known=True)
    sup.positions.calibrate(MAP)
    return sup


def running(error_limit: int = 3) -> ServoSupervisor:
    """Connected, active, start-up check passed at the neutral, torque on."""
    sup = configured(error_limit)
    sup.link.connected(0.0)
    assert sup.activate()
    assert sup.torque_on_problem(AT_NEUTRAL, frozenset(), None) is None
    sup.torque_enabled()
    return sup


# ------------------------------------------------------------------ lifecycle, link and torque
# wanted
def test_torque_is_due_only_when_active_connected_wanted_and_not_stopped() -> None:
    sup = configured()
    assert not sup.torque_due() and sup.note == "inactive"
    assert not sup.activate()  # active, but the bus is not connected yet
    assert sup.torque_wanted
    assert sup.link.connected(1.0) is None  # a first connection is not a reconnect
    assert sup.torque_due()
    sup.deactivate()
    assert not (sup.active or sup.torque_wanted or sup.torque_due())


def test_activate_discards_the_command() -> None:
    sup = running()
    sup.commands.taken(5.0)
    sup.deactivate()
    assert sup.activate()
    assert sup.commands.command_time is None and sup.commands.state is Watchdog.WAITING


def test_release_disconnects_and_deactivates() -> None:
    sup = running()
    sup.released()
    assert not (sup.link.up or sup.active or sup.torque_wanted)


def test_torque_on_and_off_bookkeeping() -> None:
    sup = running()
    assert sup.torque_on and sup.note == "on"
    assert sup.torque_disabled("deactivated") is True
    assert not sup.torque_on and sup.note == "off (deactivated)"
    assert sup.torque_disabled("again") is False  # it was already off: nothing to log as switched
    assert sup.torque_refused("too hot") is True
    assert sup.torque_refused("too hot") is False  # the same reason is logged once
    assert sup.note == "too hot"


# ------------------------------------------------------------------ set_torque
def test_set_torque_true_is_refused_while_stopped_inactive_or_disconnected() -> None:
    sup = configured()
    assert sup.set_torque_refusal() == Answer(False, "node is not active")
    sup.activate()
    sup.link.connect_failed("no such port")
    assert sup.set_torque_refusal() == Answer(False, "bus not connected: no such port")
    sup.link.connected(0.0)
    assert sup.set_torque_refusal() is None  # try it
    sup.estop.engage("estop service", 1.0)
    assert sup.set_torque_refusal() == Answer(
        False, "E-stop engaged (estop service): call clear_estop"
    )


def test_set_torque_true_when_already_on_and_after_a_try() -> None:
    sup = running()
    assert sup.set_torque_refusal() == Answer(True, "torque already on")
    sup.torque_disabled("set_torque service")
    sup.torque_unwanted()
    assert sup.set_torque_result("hardware error") == Answer(False, "hardware error")
    assert not sup.torque_wanted
    assert sup.set_torque_result(None) == Answer(True, "torque on")
    assert sup.torque_wanted and not sup.relaxed


def test_set_torque_false_keeps_torque_off_across_a_reconnect() -> None:
    sup = running()
    sup.torque_unwanted()
    sup.torque_disabled("set_torque service")
    sup.link_lost("timeout", 2.0)
    sup.link.connected(2.5)
    assert not sup.torque_due()


# ------------------------------------------------------------------ commands and watchdog
def test_command_verdicts() -> None:
    sup = running()
    assert sup.command(finite=False) is Verdict.REJECT
    assert sup.command(finite=True) is Verdict.ACCEPT
    sup.estop.engage("estop_request topic", 1.0)
    assert sup.command(finite=True) is Verdict.IGNORE
    assert sup.command(finite=False) is Verdict.REJECT  # non-finite is rejected (and counted) first


def test_watchdog_arms_with_the_first_command_and_holds() -> None:
    sup = running()
    # no command yet: nothing expires
    assert sup.check_watchdog(100.0, 0.5, "hold").event is WatchdogEvent.NONE
    sup.commands.taken(2.0)
    assert sup.commands.state is Watchdog.WAITING
    # age == timeout: not older
    assert sup.check_watchdog(2.5, 0.5, "hold").event is WatchdogEvent.NONE
    assert sup.commands.state is Watchdog.FRESH
    first = sup.check_watchdog(2.75, 0.5, "hold")
    assert first.event is WatchdogEvent.HOLD and first.stale and not first.torque_off
    assert sup.torque_on and not sup.relaxed
    assert sup.watchdog_status("hold") == "expired (hold)"
    again = sup.check_watchdog(2.76, 0.5, "hold")
    assert again.event is WatchdogEvent.STALE and again.stale  # warned once, still nothing to write
    sup.commands.taken(3.0)
    assert sup.check_watchdog(3.01, 0.5, "hold").event is WatchdogEvent.RESUMED
    assert sup.watchdog_status("hold") == "fresh"


def test_watchdog_relax_switches_torque_off_and_the_next_command_wakes() -> None:
    sup = running()
    sup.commands.taken(2.0)
    sup.check_watchdog(2.1, 0.5, "relax")
    relax = sup.check_watchdog(2.75, 0.5, "relax")
    assert relax.event is WatchdogEvent.RELAX and relax.torque_off and relax.stale
    assert sup.relaxed
    sup.torque_disabled("watchdog: no phi_cmd")
    assert sup.watchdog_status("relax") == "expired (relaxed)"
    assert not sup.torque_due()  # a reconnect does not end a relax either
    assert sup.command(finite=True) is Verdict.WAKE
    sup.torque_enabled()
    assert not sup.relaxed
    assert sup.command(finite=True) is Verdict.ACCEPT


def test_watchdog_relax_with_torque_already_off_only_reports() -> None:
    sup = running()
    sup.commands.taken(2.0)
    sup.torque_disabled("set_torque service")
    relax = sup.check_watchdog(3.0, 0.5, "relax")
    assert relax.event is WatchdogEvent.RELAX and not relax.torque_off and not sup.relaxed
    assert sup.watchdog_status("relax") == "expired (relax)"


def test_no_wake_unless_torque_is_still_wanted() -> None:
    sup = running()
    sup.commands.taken(2.0)
    sup.check_watchdog(3.0, 0.5, "relax")
    sup.torque_unwanted()  # set_torque(false) after the relax
    assert sup.command(finite=True) is Verdict.ACCEPT


def test_watchdog_off_and_cleared_command() -> None:
    sup = running()
    sup.commands.taken(2.0)
    assert sup.check_watchdog(1000.0, 0.0, "relax").event is WatchdogEvent.NONE  # timeout 0: off
    sup.commands.clear()
    assert sup.commands.command_time is None
    assert sup.watchdog_status("hold") == "waiting for the first command"
    assert sup.check_watchdog(2000.0, 0.5, "hold").event is WatchdogEvent.NONE


# ------------------------------------------------------------------ E-stop
def test_estop_latches_with_its_first_reason() -> None:
    sup = running()
    assert sup.estop.engage("estop service", 4.0) is True
    assert sup.estop.engage("estop_request topic", 5.0) is False  # idempotent
    assert sup.estop.reason == "estop service" and sup.estop.since == 4.0


def test_torque_off_outcome() -> None:
    sup = running()
    assert sup.torque_off_outcome(frozenset()) == "torque off confirmed"
    assert sup.torque_off_outcome(frozenset({23, 22})) == "torque off not confirmed by IDs [22, 23]"
    sup.link_lost("port vanished", 1.0)
    assert (
        sup.torque_off_outcome(frozenset(IDS))
        == "bus not connected (port vanished): torque off not possible"
    )


def test_estop_survives_lifecycle_and_reconnect() -> None:
    sup = running()
    sup.estop.engage("estop service", 1.0)
    sup.torque_disabled("E-stop")
    sup.deactivate()
    assert not sup.activate()  # no torque on while stopped
    sup.link_lost("timeout", 2.0)
    sup.link.connected(3.0)
    assert not sup.torque_due() and sup.estop.reason == "estop service"


def test_clear_estop_refusals_and_release() -> None:
    sup = configured()
    assert sup.clear_estop_refusal() == Answer(True, "E-stop was not engaged")
    sup.estop.engage("estop service", 1.0)
    assert sup.clear_estop_refusal() == Answer(False, "E-stop stays engaged: node is not active")
    sup.activate()
    sup.link.connect_failed("no servo answers")
    assert sup.clear_estop_refusal() == Answer(
        False, "E-stop stays engaged: bus not connected: no servo answers"
    )
    sup.link.connected(2.0)
    assert sup.clear_estop_refusal() is None  # try torque on
    assert sup.clear_estop_result("hardware error X") == Answer(
        False, "E-stop stays engaged: hardware error X"
    )
    assert sup.estop.reason == "estop service"
    sup.torque_unwanted()
    assert sup.clear_estop_result(None) == Answer(True, "E-stop cleared, torque on")
    assert sup.estop.reason is None and sup.torque_wanted and not sup.relaxed


# ------------------------------------------------------------------ link
def test_bus_is_lost_after_error_limit_failures_in_a_row() -> None:
    sup = running(error_limit=3)
    assert [sup.link.cycle_failed(port_error=False) for _ in range(2)] == [False, False]
    sup.link.cycle_succeeded()  # a good cycle restarts the count
    assert [sup.link.cycle_failed(port_error=False) for _ in range(3)] == [False, False, True]
    assert sup.link.consecutive_failures == 3


def test_port_error_loses_the_bus_at_once() -> None:
    sup = running(error_limit=3)
    assert sup.link.cycle_failed(port_error=True) is True


def test_reconnect_reports_the_outage_and_re_enables_torque() -> None:
    sup = running()
    sup.link.cycle_failed(port_error=True)
    sup.link_lost("unplugged", 10.0)
    sup.torque_disabled("bus lost")
    assert not sup.link.up and not sup.torque_due()
    assert sup.link.connect_failed("no such port") is True
    assert sup.link.connect_failed("no such port") is False  # logged once
    assert sup.link.connect_failed("servo 22 silent") is True
    assert sup.link.connected(10.75) == pytest.approx(0.75)
    assert sup.link.last_outage_s == pytest.approx(0.75) and sup.link.lost_at is None
    assert sup.link.up and sup.link.problem == "" and sup.link.consecutive_failures == 0
    assert sup.torque_due()  # still wanted: torque comes back on (if the positions are sane)
    assert sup.link.connected(11.0) is None  # no loss in between


# ------------------------------------------------------------------ torque-on retry
def _failed_torque_on(sup: ServoSupervisor) -> None:
    """A reconnect after a bus loss whose torque-on then fails."""
    sup.link_lost("servo 24 silent", 0.0)
    sup.torque_disabled("bus lost")
    sup.link.connected(1.0)
    assert sup.torque_due()


def test_a_failed_torque_on_is_retried_with_backoff_until_it_comes_on() -> None:
    sup = running()
    sup.retry.period, sup.retry.longest = 0.25, 1.5
    _failed_torque_on(sup)
    problem = "torque-on failed: write_register(64) on ID 24: There is no status packet!"
    now, delays = 1.0, []
    for _ in range(5):
        delay = sup.torque_failed(problem, now)
        assert sup.note == problem and not sup.torque_on and not sup.takes_commands()
        assert not sup.torque_retry_due(now + delay - 1e-6) and sup.torque_retry_due(now + delay)
        delays.append(delay)
        now += delay
    assert delays == [0.25, 0.5, 1.0, 1.5, 1.5]  # doubling, capped at retry_max
    assert sup.torque_enabled() == 5 and sup.takes_commands()
    assert sup.retry.at is None and not sup.torque_retry_due(now + 10.0)
    _failed_torque_on(sup)
    assert sup.torque_failed(problem, 20.0) == 0.25  # a new failure starts the backoff again
    for k in range(2000):  # hours of failures: the delay stays at retry_max
        assert sup.torque_failed(problem, 30.0 + k) == ((0.5, 1.0)[k] if k < 2 else 1.5)


@pytest.mark.parametrize(
    "end", ["refusal", "set_torque(false)", "E-stop", "bus lost", "deactivate"]
)
def test_retries_end_when_torque_is_refused_or_no_longer_due(end: str) -> None:
    sup = running()
    _failed_torque_on(sup)
    delay = sup.torque_failed("torque-on failed: no status", 1.0)
    if end == "refusal":  # the checks refuse it: the refusal stays until torque is asked for again
        sup.torque_refused("present positions of IDs [21] are outside the goal limits")
    elif end == "set_torque(false)":
        sup.torque_unwanted()
    elif end == "E-stop":
        sup.estop.engage("estop service", 1.1)
    elif end == "bus lost":  # the reconnect tries torque on itself
        sup.link_lost("unplugged", 1.1)
    else:
        sup.deactivate()
    assert not sup.torque_retry_due(1.0 + delay) and not sup.torque_retry_due(100.0)
    assert not sup.takes_commands()


def test_a_failure_while_torque_is_not_due_schedules_no_retry() -> None:
    sup = running()
    sup.torque_disabled("set_torque service")
    sup.torque_unwanted()
    assert sup.torque_failed(
        "torque-on failed: no status", 1.0
    ) is None and not sup.torque_retry_due(100.0)


def test_takes_commands_while_torque_is_on_or_relaxed_by_the_watchdog() -> None:
    sup = running()
    assert sup.takes_commands()
    sup.commands.taken(0.0)
    assert sup.check_watchdog(1.0, 0.1, "relax").torque_off
    sup.torque_disabled("watchdog: no phi_cmd")
    assert sup.takes_commands()  # the next phi_cmd switches torque on again
    sup.estop.engage("estop service", 1.0)
    assert not sup.takes_commands()


# ------------------------------------------------------------------ hardware errors
def test_hardware_error_turns_torque_off_until_asked_again() -> None:
    sup = running()
    assert sup.hardware.changed(frozenset({22}))
    assert sup.hardware_errors(frozenset({22}), {22: 4}) is Alert.FAULT
    assert not sup.torque_wanted and not sup.hardware.changed(frozenset({22}))
    assert sup.hardware.problem() == (
        "hardware error {22: 'bits 4'}: call reboot (or reboot_<id>), or power-cycle the servo"
    )
    # same errors: nothing new
    assert sup.hardware_errors(frozenset({22, 23}), {22: 4}) is Alert.NONE
    assert sup.torque_on_problem(AT_NEUTRAL, frozenset({22}), None) == sup.hardware.problem()
    assert sup.hardware_errors(frozenset(), {}) is Alert.CLEARED
    assert sup.hardware.problem() is None
    assert not sup.torque_wanted  # stays off until set_torque(true)


def test_torque_on_check_keeps_known_errors_when_none_were_read() -> None:
    sup = running()
    sup.hardware_errors(frozenset({21}), {21: 32})
    assert "hardware error" in sup.torque_on_problem(AT_NEUTRAL, frozenset(), None)
    assert sup.torque_on_problem(AT_NEUTRAL, frozenset(), {}) is None  # read and clear


# ------------------------------------------------------------------ start-up positions
def test_start_up_check_refuses_a_twisted_pose_unless_held() -> None:
    sup = configured()
    assert sup.positions.needs_held_check()
    problem = sup.torque_on_problem(TWISTED, frozenset(), None)
    assert problem is not None and "deviate" in problem and "not held" in problem
    assert not sup.positions.startup_checked
    sup.positions.held = True  # every servo still had torque on: a driver restart
    assert sup.torque_on_problem(TWISTED, frozenset(), None) is None
    assert sup.positions.startup_checked and not sup.positions.needs_held_check()


def test_start_up_check_runs_once_per_configure() -> None:
    sup = configured()
    assert sup.torque_on_problem(AT_NEUTRAL, frozenset(), None) is None
    # later: only the sane range applies
    assert sup.torque_on_problem(TWISTED, frozenset(), None) is None
    sup.configured(neutral_known=True)
    sup.positions.calibrate(MAP)
    assert sup.torque_on_problem(TWISTED, frozenset(), None) is not None


def test_sane_range_is_the_goal_limits_widened_by_the_tolerance() -> None:
    sup = configured()
    assert sup.torque_on_problem(AT_NEUTRAL, frozenset(), None) is None
    assert sup.torque_on_problem([921, 3000, -500, 5000], frozenset(), None) is None
    assert sup.torque_on_problem([920, 3000, -500, 5079], frozenset(), None) == (
        "present positions of IDs [21] are outside the goal limits (servo power-cycled or turned?)"
    )
    assert sup.torque_on_problem([920, 3000, -500, 5080], frozenset(), None).startswith(
        "present positions of IDs [21, 24] are outside"
    )


def test_first_calibration_is_refused_on_held_servos() -> None:
    sup = ServoSupervisor(IDS, 3, TOLERANCE, describe)
    sup.configured(neutral_known=False)
    assert sup.positions.needs_held_check()
    assert sup.positions.startup_checked  # nothing configured to check against
    sup.positions.held = True
    sup.positions.calibrate(MAP)  # the present positions give the map its zero
    problem = sup.positions.first_calibration("/tmp/neutral.yaml")
    assert (
        problem is not None and "no neutral file /tmp/neutral.yaml" in problem and "held" in problem
    )
    assert sup.torque_on_problem(AT_NEUTRAL, frozenset(), None) == problem  # torque stays off


def test_first_calibration_at_rest_is_accepted() -> None:
    sup = ServoSupervisor(IDS, 3, TOLERANCE, describe)
    sup.configured(neutral_known=False)
    sup.positions.calibrate(MAP)
    assert sup.positions.first_calibration("/tmp/neutral.yaml") is None
    assert not sup.positions.needs_held_check()
    assert sup.torque_on_problem(AT_NEUTRAL, frozenset(), None) is None


# ------------------------------------------------------------------ reboot
def test_reboot_refused_while_tracking_with_torque_on() -> None:
    sup = running()
    sup.commands.taken(1.0)
    sup.check_watchdog(1.01, 0.5, "hold")  # fresh
    assert "tracking" in sup.reboot_refusal()
    sup.check_watchdog(2.0, 0.5, "hold")  # expired: holding
    assert sup.reboot_refusal() is None
    sup.commands.taken(2.0)
    sup.check_watchdog(2.01, 0.5, "hold")
    sup.torque_disabled("set_torque service")
    assert sup.reboot_refusal() is None  # fresh commands but torque off


def test_reboot_refused_when_inactive_or_disconnected() -> None:
    sup = configured()
    assert sup.reboot_refusal() == "node is not active"
    sup.activate()
    assert sup.reboot_refusal() == "bus not connected"


def test_reboot_rechecks_positions_and_leaves_torque_off() -> None:
    sup = running()
    sup.hardware_errors(frozenset({22}), {22: 4})
    sup.torque_disabled("hardware error")
    sup.reboot_started()
    assert not sup.torque_wanted and not sup.relaxed
    assert sup.rebooted(AT_NEUTRAL, frozenset(), {}) is None
    assert sup.hardware.errors == {} and not sup.torque_on and not sup.torque_due()
    assert sup.set_torque_refusal() is None  # torque on only when asked, with the checks again


def test_reboot_names_the_lost_multi_turn_count_or_the_error() -> None:
    sup = running()
    sup.reboot_started()
    beyond = [1000 + 4096, 3000, -500, 5000]  # one turn off: the multi-turn count was reset
    assert sup.rebooted(beyond, frozenset(), {}) == (
        "present positions of IDs [21] are outside the goal limits (servo power-cycled or "
        "turned?); " + MULTI_TURN_NOTE
    )
    # the error, no note
    assert sup.rebooted(beyond, frozenset({21}), {21: 1}) == sup.hardware.problem()

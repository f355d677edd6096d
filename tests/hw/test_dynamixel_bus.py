"""DynamixelBus (real dynamixel_sdk underneath) against the emulated MX-28(2.0) bus, including
injected faults."""

from __future__ import annotations

import os
import threading
import time

import pytest
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT

from hsa_dynamixel_driver.bus import (
    BusError,
    CommError,
    DynamixelBus,
    PortError,
    ServoStatusError,
    describe_hardware_error,
)
from hsa_sim_node.mx28_emulator import HW_OVERHEATING, HW_OVERLOAD, MX28Emulator

ADDR_RETURN_DELAY, ADDR_MODE, ADDR_TORQUE, ADDR_GOAL = 9, 11, 64, 116


def test_open_pings_every_servo_and_checks_the_model(bus, emulator) -> None:
    assert bus.is_open and bus.ids == emulator.ids
    emulator.poke(23, 0, 1030)  # an XM430 where an MX-28 is expected
    with pytest.raises(BusError, match=r"ping on ID 23: model number 1030, expected 30") as caught:
        bus.reconnect()
    assert caught.value.dxl_id == 23 and not bus.is_open


def test_bad_arguments_fail_before_touching_the_port(emulator) -> None:
    with pytest.raises(ValueError, match="baudrate 1234567"):
        DynamixelBus(emulator.port, 1_234_567, (21,))
    with pytest.raises(ValueError, match="unique"):
        DynamixelBus(emulator.port, 4_000_000, (21, 21))


def test_missing_device_is_a_port_error(tmp_path, baud) -> None:
    with pytest.raises(PortError, match="cannot open"):
        DynamixelBus(str(tmp_path / "ttyNOPE"), baud, (21,)).open()


def test_wrong_baud_rate_names_the_first_silent_servo(emulator) -> None:
    driver = DynamixelBus(emulator.port, 1_000_000, emulator.ids)  # the servos run at 4 Mbps
    with pytest.raises(CommError, match="ping on ID 21") as caught:
        driver.open()
    assert caught.value.comm_result == COMM_RX_TIMEOUT and not driver.is_open


def test_configure_writes_eeprom_with_torque_off_then_enables(bus, emulator) -> None:
    bus.configure(return_delay=0, torque_on=True)
    for dxl_id in emulator.ids:
        assert (emulator.peek(dxl_id, ADDR_RETURN_DELAY), emulator.peek(dxl_id, ADDR_MODE)) == (
            0,
            4,
        )
        assert emulator.torque_enabled(dxl_id)
    bus.configure(return_delay=0)  # already set: EEPROM left alone, torque left off
    assert not any(emulator.torque_enabled(dxl_id) for dxl_id in emulator.ids)
    with pytest.raises(ValueError):
        bus.configure(operating_mode=16)


def test_sync_write_then_sync_read_follows_the_servo_model(bus, emulator, wait_for) -> None:
    bus.configure(torque_on=True)
    goals = {21: 2048 + 4096 * 3, 22: -5000, 23: 0, 24: 2100}
    before = emulator.stats()
    bus.write_goals(goals)
    first = bus.read_positions()
    after = emulator.stats()
    assert (after.sync_writes - before.sync_writes, after.sync_reads - before.sync_reads) == (1, 1)
    # one instruction each way, no per-servo traffic
    assert after.packets_received - before.packets_received == 2
    assert first.ticks != goals and first.alerts == frozenset()
    assert wait_for(lambda: bus.read_positions().ticks == goals)
    assert emulator.goal_ticks() == goals


def test_goals_are_validated_before_sending(bus) -> None:
    bus.configure()
    with pytest.raises(ValueError, match="IDs"):
        bus.write_goals({99: 0})
    with pytest.raises(ValueError, match="outside"):
        bus.write_goals({21: 1_048_576})  # beyond ±256 rev the servo would silently drop it
    with pytest.raises(ValueError, match="outside"):
        bus.write_goals({21: 1.5})
    bus.configure(operating_mode=3)
    with pytest.raises(ValueError, match="outside"):
        bus.write_goals({21: -1})


def test_enable_torque_holds_where_the_shaft_is(bus, emulator) -> None:
    bus.configure()
    emulator.set_present_ticks(21, 3000)  # turned by hand while limp; its stored goal is still 2048
    bus.enable_torque()
    time.sleep(0.05)
    assert emulator.goal_ticks()[21] == 3000
    assert bus.read_positions().ticks[21] == 3000


def test_eeprom_write_with_torque_on_is_refused(bus) -> None:
    bus.configure(torque_on=True)
    with pytest.raises(
        ServoStatusError, match=r"write_register\(11\) on ID 21: .*not available"
    ) as caught:
        bus.write_register(21, ADDR_MODE, 1, 3)
    assert caught.value.packet_error == 7


def test_disable_torque_is_fast_and_reports_what_it_could_not_confirm(bus, emulator) -> None:
    bus.configure(torque_on=True)
    emulator.set_responsive(22, False)
    started = time.perf_counter()
    unconfirmed = bus.disable_torque()
    # one sync write plus a read-back; the silent servo costs one timeout
    assert time.perf_counter() - started < 0.2
    assert unconfirmed == {22}
    # 22 still heard the sync write
    assert not any(emulator.torque_enabled(dxl_id) for dxl_id in emulator.ids)
    bus.close()
    assert bus.disable_torque() == set(emulator.ids)  # no port: nothing confirmed, nothing raised


def test_leaving_the_context_switches_torque_off(emulator, baud) -> None:
    with DynamixelBus(emulator.port, baud, emulator.ids) as driver:
        driver.configure(torque_on=True)
    assert not driver.is_open
    assert not any(emulator.torque_enabled(dxl_id) for dxl_id in emulator.ids)


def test_silent_servo_is_named_within_a_bounded_time_without_busy_waiting(bus, emulator) -> None:
    emulator.set_responsive(23, False)
    started_wall, started_cpu = time.perf_counter(), time.thread_time()
    with pytest.raises(CommError, match="read_positions on ID 23: .*no status packet") as caught:
        bus.read_positions()
    wall, cpu = time.perf_counter() - started_wall, time.thread_time() - started_cpu
    assert caught.value.dxl_id == 23 and caught.value.comm_result == COMM_RX_TIMEOUT
    assert 0.03 < wall < 0.1  # the SDK's 2 x 16 ms + 2 ms packet timeout
    assert cpu < 0.5 * wall  # waits in select() instead of spinning
    emulator.set_responsive(23, True)
    assert set(bus.read_positions().ticks) == set(emulator.ids)


def test_hardware_error_is_reported_and_cleared_by_reboot(bus, emulator) -> None:
    bus.configure(torque_on=True)
    emulator.set_hardware_error(22, HW_OVERLOAD | HW_OVERHEATING)
    reading = bus.read_positions()
    assert reading.alerts == {22} and set(reading.ticks) == set(emulator.ids)
    errors = bus.read_hardware_errors()
    assert errors == {21: 0, 22: 0x24, 23: 0, 24: 0}
    assert describe_hardware_error(errors[22]) == "overheating, overload"
    with pytest.raises(ServoStatusError, match="ID 22"):
        bus.enable_torque()  # shut down: only a reboot re-enables torque
    bus.reboot(22)
    assert bus.read_hardware_errors()[22] == 0 and bus.read_positions().alerts == frozenset()
    bus.enable_torque()
    assert all(emulator.torque_enabled(dxl_id) for dxl_id in emulator.ids)


def test_wait_answering_waits_for_a_booting_servo_and_gives_up_at_the_timeout(
    bus, emulator
) -> None:
    emulator.set_responsive(23, False)  # a servo still booting after a reboot does not answer
    began = time.monotonic()
    with pytest.raises(CommError, match="ping on ID 23") as caught:
        bus.wait_answering((22, 23), timeout=0.3)
    # gives up: not before the timeout, and long before the next check's timeout (bounds that hold
    # on a busy machine)
    assert caught.value.comm_result == COMM_RX_TIMEOUT and 0.3 <= time.monotonic() - began < 10.0
    wake = threading.Timer(0.2, emulator.set_responsive, (23, True))
    # before the timer starts: it cannot wake the servo sooner than 0.2 s after this
    began = time.monotonic()
    wake.start()
    bus.wait_answering((22, 23), timeout=30.0)
    # returned once the servo answered, not at the 30 s timeout
    assert 0.2 <= time.monotonic() - began < 10.0
    wake.join()


def test_unplug_gives_port_errors_until_replug_and_reconnect(bus, emulator, wait_for) -> None:
    bus.configure(torque_on=True)
    bus.write_goals({21: 2500})
    # bytes still in flight would be lost by unplug
    assert wait_for(lambda: emulator.present_ticks()[21] == 2500)
    emulator.unplug()
    with pytest.raises(PortError, match="unplugged"):
        bus.read_positions()
    with pytest.raises(PortError):
        bus.write_goals({21: 2600})
    assert bus.disable_torque() == set(emulator.ids)
    with pytest.raises(PortError, match="cannot open"):
        bus.reconnect()
    assert not bus.is_open
    emulator.replug()
    bus.reconnect()
    # the servos kept their state: only the cable was out
    assert bus.read_positions().ticks[21] == 2500
    bus.write_goals({21: 2600})


def test_corrupted_status_is_detected(bus, emulator) -> None:
    emulator.corrupt_next_statuses(1)
    with pytest.raises(CommError, match="ID 21: .*Incorrect status packet") as caught:
        bus.read_positions()
    assert caught.value.comm_result == COMM_RX_CORRUPT
    assert set(bus.read_positions().ticks) == set(emulator.ids)  # the next cycle is clean again


def test_latency_timer_check(bus, tmp_path) -> None:
    on_pty = bus.latency_timer()
    assert on_pty.value_ms is None and not on_pty.slow and "check skipped" in on_pty.describe()
    (tmp_path / "sys" / "ttyUSB7").mkdir(parents=True)
    (tmp_path / "sys" / "ttyUSB7" / "latency_timer").write_text("16\n")
    os.symlink("/dev/ttyUSB7", tmp_path / "ttyDXL7")
    ftdi = DynamixelBus(str(tmp_path / "ttyDXL7"), 4_000_000, (21,)).latency_timer(
        sysfs_root=tmp_path / "sys"
    )
    assert (ftdi.device, ftdi.value_ms, ftdi.slow) == ("/dev/ttyUSB7", 16, True)
    assert "set it to 1" in ftdi.describe()


def test_reconnect_after_a_real_power_cycle_needs_configure_again(tmp_path, baud) -> None:
    link = tmp_path / "ttyDXL"
    with MX28Emulator((1, 2), baudrate=baud, link_path=link) as emu:
        driver = DynamixelBus(str(link), baud, (1, 2))
        driver.open()
        driver.configure(return_delay=1, torque_on=True)
    with MX28Emulator(
        (1, 2), baudrate=baud, link_path=link
    ) as fresh:  # new servos: factory defaults
        driver.reconnect()
        assert not fresh.torque_enabled(1) and fresh.peek(1, ADDR_RETURN_DELAY) == 250
        driver.configure(return_delay=1)
        assert fresh.peek(1, ADDR_RETURN_DELAY) == 1
        driver.close()
    assert not emu.plugged

"""The MX-28(2.0) emulator against the Protocol 2.0 facts of the ROBOTIS e-Manual and the real
dynamixel_sdk."""

from __future__ import annotations

import os
import random
import threading
import time

import psutil
import pytest
import serial
from dynamixel_sdk import (
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from hsa_sim_node.mx28_emulator import (
    ERR_ACCESS,
    ERR_CRC,
    ERR_DATA_LENGTH,
    ERR_DATA_LIMIT,
    ERR_DATA_RANGE,
    ERR_RESULT_FAIL,
    ERRBIT_ALERT,
    HW_OVERLOAD,
    INST_PING,
    MX28Emulator,
    PacketReader,
    crc16,
    encode_packet,
    stuff,
    unstuff,
)

ADDR_MODE, ADDR_TORQUE, ADDR_WATCHDOG, ADDR_GOAL, ADDR_PRESENT = 11, 64, 98, 116, 132


# ------------------------------------------------------------------ framing (no port)
@pytest.mark.parametrize(
    ("packet_hex", "crc_hex"),
    [  # examples of the e-Manual Protocol 2.0 page
        ("FFFFFD0001030001", "194E"),  # PING ID 1
        ("FFFFFD00FE030001", "3142"),  # broadcast PING
        ("FFFFFD000107005500060426", "655D"),  # PING status, XM430 model 1030, firmware 38
        ("FFFFFD000107000284000400", "1D15"),  # READ Present Position
        (
            "FFFFFD00FE11008374000400019600000002AA000000",
            "8287",  # SYNC WRITE Goal Position of ID 1 and 2
        ),
    ],
)
def test_crc_matches_the_manual_examples(packet_hex: str, crc_hex: str) -> None:
    crc = crc16(bytes.fromhex(packet_hex))
    assert bytes([crc & 0xFF, crc >> 8]) == bytes.fromhex(crc_hex)


def test_encoding_is_byte_identical_to_the_sdk_including_stuffing() -> None:
    ph = PacketHandler(2.0)
    rng = random.Random(7)
    for _ in range(200):
        params = bytes(
            rng.choice([0xFF, 0xFD, 0x00, rng.randrange(256)]) for _ in range(rng.randrange(0, 12))
        )
        sdk_packet = [0] * (len(params) + 10)
        sdk_packet[4], sdk_packet[5], sdk_packet[6], sdk_packet[7] = (
            3,
            (len(params) + 3) & 0xFF,
            0,
            0x83,
        )
        sdk_packet[8 : 8 + len(params)] = params
        sdk_packet = ph.addStuffing(sdk_packet)
        sdk_packet[0:4] = [0xFF, 0xFF, 0xFD, 0x00]
        total = sdk_packet[5] + 7
        crc = ph.updateCRC(0, sdk_packet, total - 2)
        sdk_bytes = bytes(sdk_packet[: total - 2]) + bytes([crc & 0xFF, crc >> 8])
        assert encode_packet(3, 0x83, params) == sdk_bytes
        assert unstuff(stuff(b"\x83" + params)) == b"\x83" + params


def test_stuffing_inserts_fd_after_the_header_pattern() -> None:
    assert stuff(b"\x03\xff\xff\xfd\x01") == b"\x03\xff\xff\xfd\xfd\x01"
    assert unstuff(b"\x03\xff\xff\xfd\xfd\x01") == b"\x03\xff\xff\xfd\x01"


def test_reader_resynchronises_and_flags_bad_crc() -> None:
    good = encode_packet(21, INST_PING)
    bad = good[:-1] + bytes([good[-1] ^ 0x01])
    reader = PacketReader()
    reader.feed(b"\x00\xff\xff\x12" + good[:5])  # garbage, then a packet split across two reads
    assert reader.next_packet() is None
    reader.feed(good[5:] + bad)
    first, second = reader.next_packet(), reader.next_packet()
    assert (first.dxl_id, first.instruction, first.crc_ok) == (21, INST_PING, True)
    assert (second.dxl_id, second.crc_ok) == (21, False)
    assert reader.next_packet() is None


# ------------------------------------------------------------------ instructions through the real
# SDK
def test_ping_reports_mx28_model_and_firmware(sdk, emulator) -> None:
    port, ph = sdk
    for dxl_id in emulator.ids:
        assert ph.ping(port, dxl_id) == (30, COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 21, 6) == (45, COMM_SUCCESS, 0)
    model, result, _ = ph.ping(port, 5)
    assert (model, result) == (0, COMM_RX_TIMEOUT)


def test_broadcast_ping_finds_every_servo(sdk, emulator) -> None:
    port, ph = sdk
    found, result = ph.broadcastPing(port)
    assert result == COMM_SUCCESS
    assert found == {dxl_id: [30, 45] for dxl_id in emulator.ids}


def test_return_delay_time_delays_the_status(sdk) -> None:
    port, ph = sdk
    started = time.perf_counter()
    ph.ping(port, 21)  # factory Return Delay Time 250 = 500 µs
    assert time.perf_counter() - started >= 0.0005


def test_eeprom_is_locked_while_torque_is_on(sdk, emulator) -> None:
    port, ph = sdk
    assert ph.write1ByteTxRx(port, 21, ADDR_MODE, 4) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 21, ADDR_TORQUE, 1) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 21, ADDR_MODE, 3) == (COMM_SUCCESS, ERR_ACCESS)
    assert emulator.peek(21, ADDR_MODE) == 4
    assert ph.write1ByteTxRx(port, 21, ADDR_TORQUE, 0) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 21, ADDR_MODE, 3) == (COMM_SUCCESS, 0)


def test_write_rules_follow_the_control_table(sdk) -> None:
    port, ph = sdk
    assert ph.write1ByteTxRx(port, 21, ADDR_MODE, 2) == (COMM_SUCCESS, ERR_DATA_RANGE)  # no mode 2
    assert ph.write2ByteTxRx(port, 21, ADDR_GOAL, 100) == (
        COMM_SUCCESS,
        ERR_DATA_LENGTH,  # half of a 4-byte item
    )
    assert ph.write4ByteTxRx(port, 21, ADDR_PRESENT, 100) == (COMM_SUCCESS, ERR_ACCESS)  # read-only
    assert ph.write1ByteTxRx(port, 21, 14, 1) == (COMM_SUCCESS, ERR_ACCESS)  # undefined address
    assert ph.write4ByteTxRx(port, 21, ADDR_GOAL, 5000) == (
        COMM_SUCCESS,
        ERR_DATA_LIMIT,  # position mode: 0..4095
    )
    assert ph.readTxRx(port, 21, 200, 4)[1:] == (
        COMM_SUCCESS,
        ERR_ACCESS,  # beyond the emulated table
    )


def test_goal_moves_the_shaft_only_with_torque_on(sdk, emulator, wait_for) -> None:
    port, ph = sdk
    assert ph.write4ByteTxRx(port, 21, ADDR_GOAL, 3000) == (COMM_SUCCESS, 0)
    time.sleep(0.05)
    assert emulator.present_ticks()[21] == 2048
    # stored: a real servo jumps to it when torque comes on
    assert emulator.goal_ticks()[21] == 3000
    assert ph.write1ByteTxRx(port, 21, ADDR_TORQUE, 1) == (COMM_SUCCESS, 0)
    assert wait_for(lambda: ph.read4ByteTxRx(port, 21, ADDR_PRESENT)[0] == 3000)
    assert ph.read1ByteTxRx(port, 21, 122)[0] == 0  # Moving cleared once there


def test_extended_position_mode_goes_multi_turn_and_clear_resets_the_count(
    sdk, emulator, wait_for
) -> None:
    port, ph = sdk
    ph.write1ByteTxRx(port, 22, ADDR_MODE, 4)
    ph.write1ByteTxRx(port, 22, ADDR_TORQUE, 1)
    assert ph.write4ByteTxRx(port, 22, ADDR_GOAL, -9000) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 22, ADDR_GOAL, 2_000_000) == (
        COMM_SUCCESS,
        ERR_DATA_RANGE,  # beyond ±256 rev
    )
    assert wait_for(lambda: emulator.present_ticks()[22] == -9000)
    value, result, _ = ph.read4ByteTxRx(port, 22, ADDR_PRESENT)
    # the SDK returns the raw unsigned word
    assert result == COMM_SUCCESS and value == (-9000) & 0xFFFFFFFF
    assert ph.clearMultiTurn(port, 22) == (COMM_SUCCESS, 0)
    assert emulator.present_ticks()[22] == -9000 % 4096
    assert emulator.goal_ticks()[22] == -9000 % 4096  # the goal moves with it, so nothing turns


def test_sync_read_answers_in_the_listed_order_and_bulk_read_mixes_items(sdk, emulator) -> None:
    port, ph = sdk
    ids = emulator.ids
    for dxl_id, ticks in zip(ids, (100, 200, 300, 400)):
        emulator.set_present_ticks(dxl_id, ticks)
    reader = GroupSyncRead(port, ph, ADDR_PRESENT, 4)
    for dxl_id in reversed(ids):
        reader.addParam(dxl_id)
    assert reader.txRxPacket() == COMM_SUCCESS
    assert [reader.getData(i, ADDR_PRESENT, 4) for i in ids] == [100, 200, 300, 400]
    bulk = GroupBulkRead(port, ph)
    bulk.addParam(21, 146, 1)
    bulk.addParam(24, 144, 2)
    assert bulk.txRxPacket() == COMM_SUCCESS
    assert (bulk.getData(21, 146, 1), bulk.getData(24, 144, 2)) == (35, 120)
    stats = emulator.stats()
    assert (stats.sync_reads, stats.crc_errors) == (1, 0)


def test_hardware_error_sets_alert_trips_torque_and_needs_reboot(sdk, emulator) -> None:
    port, ph = sdk
    ph.write1ByteTxRx(port, 23, ADDR_MODE, 4)
    ph.write1ByteTxRx(port, 23, ADDR_TORQUE, 1)
    emulator.set_present_ticks(23, 5000)
    emulator.set_hardware_error(23, HW_OVERLOAD)
    assert not emulator.torque_enabled(23)  # Overload is in the default Shutdown(63) mask
    value, result, error = ph.read1ByteTxRx(port, 23, 70)
    assert (value, result, error) == (HW_OVERLOAD, COMM_SUCCESS, ERRBIT_ALERT)
    assert ph.write1ByteTxRx(port, 23, ADDR_TORQUE, 1) == (
        COMM_SUCCESS,
        ERRBIT_ALERT | ERR_RESULT_FAIL,
    )
    assert ph.reboot(port, 23) == (COMM_SUCCESS, ERRBIT_ALERT)
    assert ph.read1ByteTxRx(port, 23, 70) == (0, COMM_SUCCESS, 0)
    assert emulator.present_ticks()[23] == 5000 % 4096  # multi-turn count lost on reboot
    assert emulator.peek(23, ADDR_MODE) == 4  # EEPROM survives
    assert ph.write1ByteTxRx(port, 23, ADDR_TORQUE, 1) == (COMM_SUCCESS, 0)


def test_bus_watchdog_stops_the_servo_and_locks_goals(sdk, emulator) -> None:
    port, ph = sdk
    ph.write1ByteTxRx(port, 24, ADDR_MODE, 4)
    ph.write1ByteTxRx(port, 24, ADDR_TORQUE, 1)
    assert ph.write1ByteTxRx(port, 24, ADDR_WATCHDOG, 3) == (COMM_SUCCESS, 0)  # 60 ms
    # far away: still moving when the bus goes quiet
    ph.write4ByteTxRx(port, 24, ADDR_GOAL, 2048 + 4096 * 20)
    time.sleep(0.12)
    assert emulator.peek(24, ADDR_WATCHDOG) == -1
    stopped = emulator.present_ticks()[24]
    assert emulator.goal_ticks()[24] == stopped != 2048 + 4096 * 20
    assert ph.write4ByteTxRx(port, 24, ADDR_GOAL, 0) == (COMM_SUCCESS, ERR_DATA_RANGE)
    assert ph.write1ByteTxRx(port, 24, ADDR_WATCHDOG, 0) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 24, ADDR_GOAL, 0) == (COMM_SUCCESS, 0)


def test_status_return_level_one_answers_reads_only(sdk) -> None:
    port, ph = sdk
    assert ph.write1ByteTxRx(port, 21, 68, 1) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 21, 65, 1)[0] == COMM_RX_TIMEOUT
    assert ph.read1ByteTxRx(port, 21, 65) == (1, COMM_SUCCESS, 0)


def test_external_drive_api(tmp_path) -> None:
    with MX28Emulator((1, 2), baudrate=1_000_000, model=None, link_path=tmp_path / "dxl") as emu:
        port, ph = PortHandler(emu.port), PacketHandler(2.0)
        assert port.setBaudRate(1_000_000)
        ph.write1ByteTxRx(port, 1, ADDR_MODE, 4)
        ph.write1ByteTxRx(port, 1, ADDR_TORQUE, 1)
        ph.write4ByteTxRx(port, 1, ADDR_GOAL, -7000)
        time.sleep(0.05)
        assert emu.goal_ticks() == {1: -7000, 2: 2048}
        assert emu.present_ticks()[1] == 2048  # nothing moves on its own with model=None
        assert (emu.torque_enabled(1), emu.torque_enabled(2)) == (True, False)
        emu.set_present_ticks(1, -6999.6, velocity_ticks_per_s=300.0)
        assert ph.read4ByteTxRx(port, 1, ADDR_PRESENT)[0] == (-7000) & 0xFFFFFFFF
        # 300 ticks/s ≈ 19 units of 0.229 rpm > threshold 10
        assert ph.read1ByteTxRx(port, 1, 122)[0] == 1
        port.closePort()


def test_corrupted_instruction_is_counted_and_answered_with_crc_error(emulator, baud) -> None:
    good = encode_packet(21, INST_PING)
    with serial.Serial(emulator.port, baud, timeout=0.2) as raw:
        raw.write(good[:-2] + bytes([good[-2] ^ 0x5A, good[-1]]))
        reply = raw.read(11)
    assert reply[4] == 21 and reply[8] == ERR_CRC
    assert emulator.stats().crc_errors == 1


def test_wrong_line_speed_gets_no_answer(emulator) -> None:
    port, ph = PortHandler(emulator.port), PacketHandler(2.0)
    assert port.setBaudRate(1_000_000)  # servos are at 4 Mbps
    assert ph.ping(port, 21)[1] == COMM_RX_TIMEOUT
    assert emulator.stats().baud_mismatches == 1
    port.closePort()


def test_unplug_removes_the_device_and_replug_repoints_the_symlink(emulator, sdk, baud) -> None:
    port, ph = sdk
    emulator.unplug()
    assert not os.path.exists(emulator.port) and emulator.device is None
    with pytest.raises(Exception):
        ph.ping(port, 21)  # the open descriptor now fails with EIO
    emulator.replug()
    assert os.path.realpath(emulator.port) == emulator.device
    fresh = PortHandler(emulator.port)
    assert fresh.setBaudRate(baud)
    assert ph.ping(fresh, 21) == (30, COMM_SUCCESS, 0)
    fresh.closePort()


def test_idle_emulator_sleeps_and_stops_cleanly(tmp_path) -> None:
    emu = MX28Emulator(link_path=tmp_path / "dxl").start()
    process = psutil.Process()
    before = process.cpu_times()
    time.sleep(0.5)
    after = process.cpu_times()
    assert (after.user + after.system) - (before.user + before.system) < 0.05
    emu.stop()
    assert not any(t.name == "mx28-emulator" for t in threading.enumerate())
    assert not os.path.lexists(tmp_path / "dxl")
    own = MX28Emulator().start()
    link_dir = os.path.dirname(own.port)
    own.stop()
    assert not os.path.exists(link_dir)


def test_write_log_stamps_every_applied_write_and_skips_refused_ones(sdk, emulator) -> None:
    port, ph = sdk
    before = time.monotonic()
    assert ph.write1ByteTxRx(port, 21, ADDR_TORQUE, 1) == (COMM_SUCCESS, 0)
    # EEPROM locked: refused, not logged
    assert ph.write1ByteTxRx(port, 21, ADDR_MODE, 4)[1] == ERR_ACCESS
    writer = GroupSyncWrite(port, ph, ADDR_GOAL, 4)
    for dxl_id, goal in ((21, 3000), (22, 100), (23, -5)):  # 23 is in position mode: -5 refused
        writer.addParam(dxl_id, list(goal.to_bytes(4, "little", signed=True)))
    assert writer.txPacket() == COMM_SUCCESS
    time.sleep(0.05)
    after = time.monotonic()
    log = emulator.writes(since=before)
    assert [(w.dxl_id, w.address, w.value) for w in log] == [
        (21, ADDR_TORQUE, 1),
        (21, ADDR_GOAL, 3000),
        (22, ADDR_GOAL, 100),
    ]
    assert all(before <= w.time <= after for w in log) and log[0].time <= log[1].time
    assert [w.value for w in emulator.writes(ADDR_GOAL)] == [3000, 100]
    assert emulator.writes(since=after) == []

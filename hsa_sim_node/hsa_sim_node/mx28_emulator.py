"""Emulated bus of MX-28(2.0) Dynamixel servos speaking Protocol 2.0 on a pseudo-terminal (no ROS).

The real ``dynamixel_sdk`` (or any Protocol 2.0 client) opens ``emulator.port`` like a U2D2 device. Protocol facts
follow the ROBOTIS e-Manual (Protocol 2.0 and MX-28(2.0) pages); behaviour the manual leaves open is marked
"assumption".
"""

from __future__ import annotations

import math
import os
import select
import shutil
import tempfile
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import NamedTuple

from hsa_core.actuation import ServoModel

# Protocol 2.0 framing and instruction set.
HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REBOOT = 0x08
INST_CLEAR = 0x10
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_BULK_READ = 0x92

# Status packet error field: bit 7 is the hardware alert, bits 0-6 the error number.
ERRBIT_ALERT = 0x80
ERR_RESULT_FAIL = 0x01
ERR_INSTRUCTION = 0x02
ERR_CRC = 0x03
ERR_DATA_RANGE = 0x04
ERR_DATA_LENGTH = 0x05
ERR_DATA_LIMIT = 0x06
ERR_ACCESS = 0x07

# Hardware Error Status (70) / Shutdown (63) bits.
HW_INPUT_VOLTAGE = 0x01
HW_OVERHEATING = 0x04
HW_MOTOR_ENCODER = 0x08
HW_ELECTRICAL_SHOCK = 0x10
HW_OVERLOAD = 0x20

MX28_MODEL_NUMBER = 30
MX28_FIRMWARE = 45
TICKS_PER_REV = 4096
EXTENDED_GOAL_LIMIT = 1_048_575  # ±256 rev in Extended Position Control Mode
BAUD_RATE_CODES = {9600: 0, 57600: 1, 115200: 2, 1_000_000: 3, 2_000_000: 4, 3_000_000: 5, 4_000_000: 6, 4_500_000: 7}
# termios speed constant -> Baud Rate(8) code, for the rates this platform's termios knows.
_SPEED_CODES = {
    getattr(termios, f"B{rate}"): code for rate, code in BAUD_RATE_CODES.items() if hasattr(termios, f"B{rate}")
}

_MAX_PACKET_LENGTH = 1024  # longest Length field accepted before resynchronising on the next header
_STALE_INPUT_S = 0.1  # an incomplete packet older than this is discarded (the wire went quiet mid-packet)
_POLL_S = 0.1  # select timeout of the serving thread; it only bounds how long stale input lingers


def _make_crc_table() -> tuple[int, ...]:
    """Table of the non-reflected CRC-16 with polynomial 0x8005 and initial value 0 used by Protocol 2.0."""
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_crc_table()


def crc16(data: bytes | bytearray) -> int:
    """Protocol 2.0 CRC of ``data`` (header to last parameter, stuffing included)."""
    crc = 0
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes | bytearray) -> bytes:
    """Byte-stuff instruction+parameters: every 0xFF 0xFF 0xFD gets an extra 0xFD so it cannot look like a header."""
    if HEADER[:3] not in body:
        return bytes(body)
    out = bytearray()
    for i, byte in enumerate(body):
        out.append(byte)
        if byte == 0xFD and i >= 2 and body[i - 1] == 0xFF and body[i - 2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes | bytearray) -> bytes:
    """Undo :func:`stuff`: 0xFF 0xFF 0xFD 0xFD becomes 0xFF 0xFF 0xFD."""
    if HEADER[:3] not in body:
        return bytes(body)
    out = bytearray()
    i = 0
    while i < len(body):
        byte = body[i]
        out.append(byte)
        stuffed = byte == 0xFD and i >= 2 and body[i - 1] == 0xFF and body[i - 2] == 0xFF
        i += 2 if stuffed and i + 1 < len(body) and body[i + 1] == 0xFD else 1
    return bytes(out)


def encode_packet(dxl_id: int, instruction: int, params: bytes | bytearray = b"") -> bytes:
    """Complete Protocol 2.0 packet (header, ID, length, stuffed instruction+params, CRC)."""
    body = stuff(bytes([instruction]) + bytes(params))
    length = len(body) + 2
    head = HEADER + bytes([dxl_id, length & 0xFF, length >> 8])
    crc = crc16(head + body)
    return head + body + bytes([crc & 0xFF, crc >> 8])


@dataclass(frozen=True)
class Packet:
    """One received packet, already unstuffed; ``crc_ok`` is False when the CRC did not match."""

    dxl_id: int
    instruction: int
    params: bytes
    crc_ok: bool


class PacketReader:
    """Reassembles packets from a byte stream: header search, length, CRC check, unstuffing."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def __len__(self) -> int:
        return len(self._buffer)

    def feed(self, data: bytes) -> None:
        """Append received bytes."""
        self._buffer += data

    def clear(self) -> None:
        """Drop buffered bytes (a partial packet whose remainder never came)."""
        self._buffer.clear()

    def next_packet(self) -> Packet | None:
        """Next complete packet, or None until more bytes arrive; malformed headers are skipped byte by byte."""
        buf = self._buffer
        while True:
            start = buf.find(HEADER[:3])
            if start < 0:
                del buf[: max(0, len(buf) - 2)]  # keep a possible partial header
                return None
            del buf[:start]
            if len(buf) < 7:
                return None
            dxl_id, length = buf[4], buf[5] | buf[6] << 8
            if buf[3] != 0x00 or dxl_id in (0xFD, 0xFF) or not 3 <= length <= _MAX_PACKET_LENGTH:
                del buf[0]
                continue
            if len(buf) < 7 + length:
                return None
            raw = bytes(buf[: 7 + length])
            del buf[: 7 + length]
            body = unstuff(raw[7:-2])
            crc_ok = crc16(raw[:-2]) == raw[-2] | raw[-1] << 8
            return Packet(dxl_id, body[0], body[1:], crc_ok)


@dataclass(frozen=True)
class _Item:
    """One control-table entry; ``valid`` lists accepted write values (None: anything that fits in ``size`` bytes)."""

    address: int
    size: int
    default: int = 0
    writable: bool = True
    signed: bool = False
    valid: range | frozenset[int] | None = None


# MX-28(2.0) control table (e-Manual). EEPROM is addresses < 64. Indirect addresses/data are not emulated.
ADDR_MODEL_NUMBER = 0
ADDR_FIRMWARE = 6
ADDR_ID = 7
ADDR_BAUD_RATE = 8
ADDR_RETURN_DELAY = 9
ADDR_OPERATING_MODE = 11
ADDR_MOVING_THRESHOLD = 24
ADDR_MAX_POSITION = 48
ADDR_MIN_POSITION = 52
ADDR_SHUTDOWN = 63
ADDR_TORQUE_ENABLE = 64
ADDR_STATUS_RETURN_LEVEL = 68
ADDR_HARDWARE_ERROR = 70
ADDR_BUS_WATCHDOG = 98
ADDR_GOAL_PWM = 100
ADDR_GOAL_VELOCITY = 104
ADDR_GOAL_POSITION = 116
ADDR_REALTIME_TICK = 120
ADDR_MOVING = 122
ADDR_PRESENT_LOAD = 126
ADDR_PRESENT_VELOCITY = 128
ADDR_PRESENT_POSITION = 132
ADDR_PRESENT_VOLTAGE = 144
ADDR_PRESENT_TEMPERATURE = 146
EEPROM_END = 64
TABLE_SIZE = 147

_ITEMS = {
    item.address: item
    for item in (
        _Item(ADDR_MODEL_NUMBER, 2, MX28_MODEL_NUMBER, writable=False),
        _Item(2, 4, 0, writable=False),  # Model Information
        _Item(ADDR_FIRMWARE, 1, MX28_FIRMWARE, writable=False),
        _Item(ADDR_ID, 1, 1, valid=range(0, MAX_ID + 1)),
        _Item(ADDR_BAUD_RATE, 1, 1, valid=range(0, 8)),
        _Item(ADDR_RETURN_DELAY, 1, 250, valid=range(0, 255)),
        _Item(10, 1, 0),  # Drive Mode
        _Item(ADDR_OPERATING_MODE, 1, 3, valid=frozenset({1, 3, 4, 16})),
        _Item(12, 1, 255),  # Secondary (Shadow) ID
        _Item(13, 1, 2, valid=range(1, 3)),  # Protocol Version
        _Item(20, 4, 0, signed=True),  # Homing Offset (stored, not applied)
        _Item(ADDR_MOVING_THRESHOLD, 4, 10, valid=range(0, 1024)),
        _Item(31, 1, 80),  # Temperature Limit
        _Item(32, 2, 160),  # Max Voltage Limit
        _Item(34, 2, 95),  # Min Voltage Limit
        _Item(36, 2, 885),  # PWM Limit
        _Item(40, 4, 32767),  # Acceleration Limit
        _Item(44, 4, 380),  # Velocity Limit
        _Item(ADDR_MAX_POSITION, 4, TICKS_PER_REV - 1, valid=range(0, TICKS_PER_REV)),
        _Item(ADDR_MIN_POSITION, 4, 0, valid=range(0, TICKS_PER_REV)),
        _Item(ADDR_SHUTDOWN, 1, HW_OVERHEATING | HW_ELECTRICAL_SHOCK | HW_OVERLOAD),
        _Item(ADDR_TORQUE_ENABLE, 1, 0, valid=range(0, 2)),
        _Item(65, 1, 0, valid=range(0, 2)),  # LED
        _Item(ADDR_STATUS_RETURN_LEVEL, 1, 2, valid=range(0, 3)),
        _Item(69, 1, 0, writable=False),  # Registered Instruction
        _Item(ADDR_HARDWARE_ERROR, 1, 0, writable=False),
        _Item(76, 2, 1920),  # Velocity I Gain
        _Item(78, 2, 100),  # Velocity P Gain
        _Item(80, 2, 0),  # Position D Gain
        _Item(82, 2, 0),  # Position I Gain
        _Item(84, 2, 850),  # Position P Gain
        _Item(88, 2, 0),  # Feedforward 2nd Gain
        _Item(90, 2, 0),  # Feedforward 1st Gain
        _Item(ADDR_BUS_WATCHDOG, 1, 0, signed=True, valid=range(0, 128)),
        _Item(ADDR_GOAL_PWM, 2, 885, signed=True),
        _Item(ADDR_GOAL_VELOCITY, 4, 0, signed=True),
        _Item(108, 4, 0),  # Profile Acceleration
        _Item(112, 4, 0),  # Profile Velocity
        _Item(ADDR_GOAL_POSITION, 4, 0, signed=True),
        _Item(ADDR_REALTIME_TICK, 2, 0, writable=False),
        _Item(ADDR_MOVING, 1, 0, writable=False),
        _Item(123, 1, 0, writable=False),  # Moving Status
        _Item(124, 2, 0, writable=False, signed=True),  # Present PWM
        _Item(ADDR_PRESENT_LOAD, 2, 0, writable=False, signed=True),
        _Item(ADDR_PRESENT_VELOCITY, 4, 0, writable=False, signed=True),
        _Item(ADDR_PRESENT_POSITION, 4, 0, writable=False, signed=True),
        _Item(136, 4, 0, writable=False, signed=True),  # Velocity Trajectory
        _Item(140, 4, 0, writable=False, signed=True),  # Position Trajectory
        _Item(ADDR_PRESENT_VOLTAGE, 2, 120, writable=False),  # 0.1 V
        _Item(ADDR_PRESENT_TEMPERATURE, 1, 35, writable=False),  # °C
    )
}
# Byte address -> item it belongs to, for detecting writes that cut an item or touch undefined addresses.
_OWNER = {a: item for item in _ITEMS.values() for a in range(item.address, item.address + item.size)}
_GOALS = (ADDR_GOAL_PWM, ADDR_GOAL_VELOCITY, ADDR_GOAL_POSITION)  # read-only while a bus-watchdog error is latched
_COMPUTED = (ADDR_REALTIME_TICK, ADDR_MOVING, ADDR_PRESENT_VELOCITY, ADDR_PRESENT_POSITION)
_VELOCITY_UNIT_RPM = 0.229


class RegisterWrite(NamedTuple):
    """One control-table item changed by a WRITE or SYNC_WRITE, stamped when the emulator executed the packet."""

    time: float  # time.monotonic() (CLOCK_MONOTONIC, comparable between processes of one machine)
    dxl_id: int
    address: int
    value: int


@dataclass
class EmulatorStats:
    """Traffic counters of the emulated bus."""

    packets_received: int = 0
    crc_errors: int = 0
    sync_writes: int = 0
    sync_reads: int = 0
    statuses_sent: int = 0
    baud_mismatches: int = 0


class _Journal(deque):
    """The emulator's write log: a bounded deque that also counts every entry ever appended."""

    def __init__(self, maxlen: int) -> None:
        super().__init__(maxlen=maxlen)
        self.appended = 0

    def append(self, write: RegisterWrite) -> None:
        super().append(write)
        self.appended += 1


class _Servo:
    """Control table and shaft state of one emulated MX-28(2.0)."""

    def __init__(self, dxl_id: int, baud_code: int, ticks: int, model: ServoModel | None, now: float) -> None:
        self.table = bytearray(TABLE_SIZE)
        for item in _ITEMS.values():
            self.put(item.address, item.default)
        self.put(ADDR_ID, dxl_id)
        self.put(ADDR_BAUD_RATE, baud_code)
        self.position = float(ticks)
        self.velocity = 0.0
        self.put(ADDR_GOAL_POSITION, ticks)  # assumption: at power-on the goal equals the present position
        self.model = model
        self.responsive = True
        self.updated = now
        self.last_instruction = now
        self.journal: deque[RegisterWrite] | None = None  # the emulator's write log, if it keeps one

    @property
    def dxl_id(self) -> int:
        return self.table[ADDR_ID]

    @property
    def torque_on(self) -> bool:
        return self.table[ADDR_TORQUE_ENABLE] == 1

    def get(self, address: int) -> int:
        """Value of the item at ``address`` (with its size and signedness)."""
        item = _ITEMS[address]
        return int.from_bytes(self.table[address : address + item.size], "little", signed=item.signed)

    def put(self, address: int, value: int) -> None:
        """Store ``value`` in the item at ``address`` without any access check."""
        item = _ITEMS[address]
        self.table[address : address + item.size] = int(value).to_bytes(item.size, "little", signed=item.signed)

    def error_byte(self, error: int) -> int:
        """Status error field: the error number plus the alert bit while a hardware error is latched."""
        return error | (ERRBIT_ALERT if self.table[ADDR_HARDWARE_ERROR] else 0)

    def advance(self, now: float) -> None:
        """Move the shaft to time ``now``, tripping the bus watchdog at its exact expiry time if due."""
        watchdog = self.get(ADDR_BUS_WATCHDOG)
        if self.torque_on and watchdog > 0:
            expiry = self.last_instruction + watchdog * 0.020
            if expiry < now:
                self._follow(expiry)
                self.put(ADDR_GOAL_POSITION, round(self.position))  # the servo stops where it is
                self.put(ADDR_BUS_WATCHDOG, -1)
        self._follow(now)

    def _follow(self, now: float) -> None:
        dt = now - self.updated
        if dt <= 0.0:
            return
        self.updated = now
        if self.model is None:
            return
        if self.torque_on and self.get(ADDR_OPERATING_MODE) in (3, 4):
            self.position, self.velocity = self.model.step(self.position, self.get(ADDR_GOAL_POSITION), dt)
        else:
            self.velocity = 0.0

    def refresh(self, now: float) -> None:
        """Update the computed registers (present position/velocity, moving, realtime tick) for a read at ``now``."""
        self.advance(now)
        self.put(ADDR_PRESENT_POSITION, max(-(2**31), min(2**31 - 1, round(self.position))))
        velocity = round(self.velocity * 60.0 / TICKS_PER_REV / _VELOCITY_UNIT_RPM)
        self.put(ADDR_PRESENT_VELOCITY, velocity)
        self.put(ADDR_MOVING, int(abs(velocity) > self.get(ADDR_MOVING_THRESHOLD)))
        self.put(ADDR_REALTIME_TICK, int(now * 1000) % 32768)

    def wrap_to_one_turn(self) -> None:
        """Reset the multi-turn count: present (and goal) move into one absolute rotation, the shaft stays put."""
        offset = math.floor(self.position / TICKS_PER_REV) * TICKS_PER_REV
        self.position -= offset
        self.put(ADDR_GOAL_POSITION, self.get(ADDR_GOAL_POSITION) - offset)

    def read(self, address: int, length: int, now: float) -> tuple[int, bytes]:
        """READ semantics: (error number, data)."""
        if length == 0 or address + length > TABLE_SIZE:
            return ERR_ACCESS, b""
        self.refresh(now)
        return 0, bytes(self.table[address : address + length])

    def write(self, address: int, data: bytes, now: float) -> int:
        """WRITE semantics, all-or-nothing: returns the error number (0 when applied, then journaled at ``now``)."""
        staged: list[tuple[_Item, int]] = []
        pos, end = address, address + len(data)
        if not data:
            return ERR_DATA_LENGTH
        while pos < end:
            item = _ITEMS.get(pos)
            if item is None:
                return ERR_DATA_LENGTH if pos in _OWNER else ERR_ACCESS
            if pos + item.size > end:
                return ERR_DATA_LENGTH
            if not item.writable or (item.address < EEPROM_END and self.torque_on):
                return ERR_ACCESS
            value = int.from_bytes(data[pos - address : pos - address + item.size], "little", signed=item.signed)
            error = self._check(item, value)
            if error:
                return error
            staged.append((item, value))
            pos += item.size
        for item, value in staged:
            self._apply(item, value)
            if self.journal is not None:
                self.journal.append(RegisterWrite(now, self.dxl_id, item.address, value))
        return 0

    def _check(self, item: _Item, value: int) -> int:
        if item.valid is not None and value not in item.valid:
            return ERR_DATA_RANGE
        if item.address in _GOALS and self.get(ADDR_BUS_WATCHDOG) == -1:
            return ERR_DATA_RANGE
        if item.address == ADDR_GOAL_POSITION:
            if self.get(ADDR_OPERATING_MODE) == 4:
                return ERR_DATA_RANGE if abs(value) > EXTENDED_GOAL_LIMIT else 0
            if not self.get(ADDR_MIN_POSITION) <= value <= self.get(ADDR_MAX_POSITION):
                return ERR_DATA_LIMIT
        if item.address == ADDR_TORQUE_ENABLE and value == 1 and self._shut_down():
            return ERR_RESULT_FAIL  # assumption: only REBOOT re-enables torque after a shutdown
        return 0

    def _shut_down(self) -> bool:
        return bool(self.table[ADDR_HARDWARE_ERROR] & self.table[ADDR_SHUTDOWN])

    def _apply(self, item: _Item, value: int) -> None:
        self.put(item.address, value)
        position_mode = self.get(ADDR_OPERATING_MODE) == 3
        if item.address == ADDR_OPERATING_MODE and position_mode:
            self.wrap_to_one_turn()
        if item.address == ADDR_TORQUE_ENABLE and value == 1 and position_mode:
            self.wrap_to_one_turn()

    def reboot(self) -> None:
        """REBOOT: RAM back to defaults, errors cleared, torque off, present position within one turn."""
        for item in _ITEMS.values():
            if (item.address >= EEPROM_END and item.writable) or item.address == ADDR_HARDWARE_ERROR:
                self.put(item.address, item.default)
        self.wrap_to_one_turn()
        self.put(ADDR_GOAL_POSITION, round(self.position))
        self.velocity = 0.0

    def set_hardware_error(self, bits: int) -> None:
        """Latch hardware error bits; bits enabled in Shutdown(63) switch the torque off."""
        self.put(ADDR_HARDWARE_ERROR, bits)
        if self._shut_down():
            self.put(ADDR_TORQUE_ENABLE, 0)


class MX28Emulator:
    """A pseudo-terminal bus of N MX-28(2.0) servos served by a background thread; also the simulator's servo API.

    Goal Position is stored while torque is off but only moves the shaft with torque on (a servo whose goal was written
    with torque off moves to it when torque is switched on, as real ones do). With ``model=None`` the shaft is driven
    externally through :meth:`set_present_ticks`.
    """

    def __init__(
        self,
        ids: Iterable[int] = (21, 22, 23, 24),
        *,
        baudrate: int = 4_000_000,
        model: ServoModel | None = ServoModel(),
        initial_ticks: Mapping[int, int] | None = None,
        link_path: str | os.PathLike[str] | None = None,
        check_baud: bool = True,
        write_log_size: int = 65_536,
    ) -> None:
        if baudrate not in BAUD_RATE_CODES:
            raise ValueError(f"baudrate {baudrate} is not an MX-28(2.0) rate {sorted(BAUD_RATE_CODES)}")
        ids = tuple(ids)
        if not ids or len(set(ids)) != len(ids) or not all(0 <= i <= MAX_ID for i in ids):
            raise ValueError(f"ids must be unique integers in 0..{MAX_ID}, got {ids}")
        now = time.monotonic()
        ticks = dict(initial_ticks or {})
        self._servos = [_Servo(i, BAUD_RATE_CODES[baudrate], ticks.get(i, 2048), model, now) for i in ids]
        self._journal = _Journal(write_log_size)
        self._busy = False  # the serving thread is between reading bytes and finishing their packets
        self._drained = 0
        for servo in self._servos:
            servo.journal = self._journal
        self._check_baud = check_baud
        self._lock = threading.Lock()
        self._stats = EmulatorStats()
        self._corrupt_statuses = 0
        self._own_dir = None if link_path is not None else Path(tempfile.mkdtemp(prefix="mx28emu-"))
        self._link = Path(link_path) if link_path is not None else self._own_dir / "ttyDXL"
        self._master: int | None = None
        self._slave: int | None = None
        self._wake: tuple[int, int] | None = None
        self._thread: threading.Thread | None = None

    # ---------------------------------------------------------------- lifecycle
    @property
    def port(self) -> str:
        """Stable device path (a symlink re-pointed on every replug); give this to the driver."""
        return str(self._link)

    @property
    def device(self) -> str | None:
        """Current pseudo-terminal slave (e.g. /dev/pts/3), None while unplugged."""
        return os.ttyname(self._slave) if self._slave is not None else None

    @property
    def plugged(self) -> bool:
        return self._thread is not None

    def start(self) -> MX28Emulator:
        """Create the pseudo-terminal, point the symlink at it and start serving."""
        if self._thread is None:
            self._plug()
        return self

    def stop(self) -> None:
        """Stop serving, close the pseudo-terminal and remove the symlink (and its directory if we made it)."""
        self.unplug()
        if self._own_dir is not None:
            shutil.rmtree(self._own_dir, ignore_errors=True)

    def __enter__(self) -> MX28Emulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def unplug(self) -> None:
        """Make the device disappear: the driver's open port starts failing with EIO and the symlink is removed."""
        if self._thread is None:
            return
        assert self._wake is not None
        os.write(self._wake[1], b"x")
        self._thread.join()
        for fd in (self._master, self._slave, *self._wake):
            os.close(fd)
        self._master = self._slave = self._wake = self._thread = None
        self._link.unlink(missing_ok=True)

    def replug(self) -> None:
        """Plug the bus back in on a fresh pseudo-terminal; the symlink now points at it (servo state is kept)."""
        if self._thread is None:
            self._plug()

    def _plug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # before any client opens it, or the line discipline mangles the first bytes
        os.set_blocking(master, False)
        self._master, self._slave, self._wake = master, slave, os.pipe()
        staging = self._link.with_name(self._link.name + ".new")
        staging.unlink(missing_ok=True)
        os.symlink(os.ttyname(slave), staging)
        os.replace(staging, self._link)
        self._thread = threading.Thread(target=self._serve, args=(master, self._wake[0]), name="mx28-emulator")
        self._thread.daemon = True
        self._thread.start()

    # ---------------------------------------------------------------- simulator API
    @property
    def ids(self) -> tuple[int, ...]:
        """Current servo IDs (an ID can be changed over the bus)."""
        with self._lock:
            return tuple(s.dxl_id for s in self._servos)

    def goal_ticks(self) -> dict[int, int]:
        """Goal Position register of every servo."""
        with self._lock:
            now = time.monotonic()
            for servo in self._servos:
                servo.advance(now)
            return {s.dxl_id: s.get(ADDR_GOAL_POSITION) for s in self._servos}

    def present_ticks(self) -> dict[int, int]:
        """Present Position of every servo, as a READ would return it now."""
        with self._lock:
            now = time.monotonic()
            for servo in self._servos:
                servo.refresh(now)
            return {s.dxl_id: s.get(ADDR_PRESENT_POSITION) for s in self._servos}

    def set_present_ticks(self, dxl_id: int, ticks: float, velocity_ticks_per_s: float = 0.0) -> None:
        """Set the shaft position (and velocity) from outside, e.g. from the simulator's model."""
        with self._lock:
            servo = self._servo(dxl_id)
            servo.advance(time.monotonic())
            servo.position, servo.velocity = float(ticks), float(velocity_ticks_per_s)

    def torque_enabled(self, dxl_id: int) -> bool:
        """Whether the servo's torque is on (after any bus-watchdog or shutdown event up to now)."""
        with self._lock:
            servo = self._servo(dxl_id)
            servo.advance(time.monotonic())
            return servo.torque_on

    def peek(self, dxl_id: int, address: int) -> int:
        """Value of the control-table item starting at ``address`` (size and sign from the MX-28(2.0) table)."""
        with self._lock:
            servo = self._servo(dxl_id)
            servo.refresh(time.monotonic())
            return servo.get(address)

    def poke(self, dxl_id: int, address: int, value: int) -> None:
        """Overwrite an item bypassing access rules (temperature, voltage, load, model number...) for tests."""
        if address in _COMPUTED:
            raise ValueError(f"address {address} is computed from the shaft state; use set_present_ticks")
        with self._lock:
            self._servo(dxl_id).put(address, value)

    # ---------------------------------------------------------------- fault injection
    def set_responsive(self, dxl_id: int, responsive: bool) -> None:
        """A non-responsive servo still executes instructions but never sends a status packet (like a cut wire)."""
        with self._lock:
            self._servo(dxl_id).responsive = responsive

    def set_hardware_error(self, dxl_id: int, bits: int) -> None:
        """Latch Hardware Error Status bits (e.g. HW_OVERLOAD); statuses then carry the alert bit, torque may trip."""
        with self._lock:
            self._servo(dxl_id).set_hardware_error(bits)

    def corrupt_next_statuses(self, count: int = 1) -> None:
        """Send the next ``count`` status packets with a wrong CRC."""
        with self._lock:
            self._corrupt_statuses += count

    def writes(self, address: int | None = None, since: float = -math.inf) -> list[RegisterWrite]:
        """Logged register writes (all, or of the item at ``address``) executed at or after ``since``, oldest first.

        The log keeps the newest ``write_log_size`` entries.
        """
        with self._lock:
            return [w for w in self._journal if w.time >= since and (address is None or w.address == address)]

    def idle(self) -> bool:
        """No byte the client wrote is left unexecuted (the simulator's check that a write has landed): nothing
        unread on the line and the serving thread not between a read and the end of its packets."""
        if self._busy or self._master is None:
            return not self._busy
        readable, _, _ = select.select([self._master], [], [], 0.0)
        return not readable and not self._busy

    def drain_writes(self, address: int) -> list[RegisterWrite]:
        """Writes of the item at ``address`` logged since the previous call, oldest first (the simulator's feed)."""
        with self._lock:
            new = min(self._journal.appended - self._drained, len(self._journal))
            self._drained = self._journal.appended
            fresh = [self._journal[i] for i in range(len(self._journal) - new, len(self._journal))]
        return [w for w in fresh if w.address == address]

    def unresponsive(self) -> tuple[int, ...]:
        """IDs of the servos made silent by :meth:`set_responsive`."""
        with self._lock:
            return tuple(s.dxl_id for s in self._servos if not s.responsive)

    def hardware_errors(self) -> dict[int, int]:
        """Latched Hardware Error Status of every servo."""
        with self._lock:
            return {s.dxl_id: s.table[ADDR_HARDWARE_ERROR] for s in self._servos}

    def stats(self) -> EmulatorStats:
        """Snapshot of the traffic counters."""
        with self._lock:
            return EmulatorStats(**{f.name: getattr(self._stats, f.name) for f in fields(EmulatorStats)})

    # ---------------------------------------------------------------- serving
    def _servo(self, dxl_id: int) -> _Servo:
        for servo in self._servos:
            if servo.dxl_id == dxl_id:
                return servo
        raise KeyError(f"no emulated servo with ID {dxl_id}")

    def _serve(self, master: int, wake: int) -> None:
        reader = PacketReader()
        last_byte = time.monotonic()
        while True:
            ready, _, _ = select.select([master, wake], [], [], _POLL_S)
            if wake in ready:
                return
            if not ready:
                if len(reader) and time.monotonic() - last_byte > _STALE_INPUT_S:
                    reader.clear()
                continue
            self._busy = True  # before the read: see idle()
            try:
                reader.feed(os.read(master, 4096))
            except BlockingIOError:
                self._busy = False
                continue
            last_byte = time.monotonic()
            while (packet := reader.next_packet()) is not None:
                for delay_s, status in self._handle(packet, master):
                    if delay_s > 0.0:
                        time.sleep(delay_s)
                    try:
                        os.write(master, status)
                    except BlockingIOError:
                        pass  # nobody reads the port and its buffer is full: the bytes are lost, as on a wire
            self._busy = False

    def _handle(self, packet: Packet, master: int) -> list[tuple[float, bytes]]:
        """Execute one instruction packet; returns (return delay, status packet) pairs to send in order."""
        with self._lock:
            now = time.monotonic()
            replies: list[tuple[int, _Servo, int, bytes]] = []
            if not packet.crc_ok:
                self._stats.crc_errors += 1
                replies = [(0, s, s.error_byte(ERR_CRC), b"") for s in self._servos if s.dxl_id == packet.dxl_id]
            else:
                self._count(packet)
                code = self._line_baud_code(master)
                for servo in self._servos:
                    servo.advance(now)
                    servo.last_instruction = now
                deaf = [s for s in self._servos if code is not None and code != s.table[ADDR_BAUD_RATE]]
                self._stats.baud_mismatches += bool(deaf)  # those servos only see garbage at the wrong rate
                for servo in self._servos:
                    if servo not in deaf:
                        replies += [(slot, servo, err, data) for slot, err, data in self._execute(servo, packet, now)]
            replies.sort(key=lambda reply: reply[0])  # stable: sync-read order, or ID order for a broadcast ping
            return [self._status(servo, err, data) for _, servo, err, data in replies if servo.responsive]

    def _count(self, packet: Packet) -> None:
        self._stats.packets_received += 1
        self._stats.sync_writes += packet.instruction == INST_SYNC_WRITE
        self._stats.sync_reads += packet.instruction == INST_SYNC_READ

    def _line_baud_code(self, master: int) -> int | None:
        """Baud Rate(8) code of the line speed the client set (-1: not an MX-28 rate), or None when not checked."""
        if not self._check_baud:
            return None
        return _SPEED_CODES.get(termios.tcgetattr(master)[5], -1)

    @staticmethod
    def _execute(servo: _Servo, packet: Packet, now: float) -> list[tuple[int, int, bytes]]:
        """One servo's part of an instruction: (reply slot, status error field, data) for each status it owes."""
        inst, params, unicast = packet.instruction, packet.params, packet.dxl_id == servo.dxl_id
        level = servo.table[ADDR_STATUS_RETURN_LEVEL]
        if not unicast and packet.dxl_id != BROADCAST_ID:
            return []
        if inst == INST_PING:  # answered at every Status Return Level
            return [(servo.dxl_id, servo.error_byte(0), bytes(servo.table[0:2] + servo.table[ADDR_FIRMWARE:7]))]
        if inst == INST_SYNC_WRITE and not unicast:
            _sync_write(servo, params, now)
            return []
        if inst in (INST_SYNC_READ, INST_BULK_READ) and not unicast:
            slot, address, length = _group_read_request(servo.dxl_id, inst, params)
            if slot is None or level < 1:
                return []
            error, data = servo.read(address, length, now)
            return [(slot, servo.error_byte(error), data)]
        if inst == INST_WRITE:
            error = servo.write(_u16(params, 0), params[2:], now) if len(params) >= 3 else ERR_INSTRUCTION
            return [(0, servo.error_byte(error), b"")] if unicast and level == 2 else []
        if not unicast:
            return []  # READ, REBOOT, CLEAR and unknown instructions get no broadcast reply
        if inst == INST_READ:
            if len(params) != 4:
                return [(0, servo.error_byte(ERR_INSTRUCTION), b"")] if level >= 1 else []
            error, data = servo.read(_u16(params, 0), _u16(params, 2), now)
            return [(0, servo.error_byte(error), data)] if level >= 1 else []
        if inst == INST_REBOOT:
            field = servo.error_byte(0)  # the status leaves before the reboot clears the error
            servo.reboot()
            return [(0, field, b"")] if level == 2 else []
        error = _clear(servo, params) if inst == INST_CLEAR else ERR_INSTRUCTION
        return [(0, servo.error_byte(error), b"")] if level == 2 else []

    def _status(self, servo: _Servo, error_field: int, params: bytes) -> tuple[float, bytes]:
        """A status packet from ``servo`` and the Return Delay Time (2 µs units) to wait before sending it."""
        payload = encode_packet(servo.dxl_id, INST_STATUS, bytes([error_field]) + params)
        if self._corrupt_statuses:
            self._corrupt_statuses -= 1
            payload = payload[:-2] + bytes([payload[-2] ^ 0xFF, payload[-1]])
        self._stats.statuses_sent += 1
        return servo.table[ADDR_RETURN_DELAY] * 2e-6, payload


def _sync_write(servo: _Servo, params: bytes, now: float) -> None:
    """Apply ``servo``'s slice of a SYNC_WRITE (no status is ever returned)."""
    if len(params) < 4:
        return
    address, length = _u16(params, 0), _u16(params, 2)
    for offset in range(4, len(params) - length, length + 1):
        if params[offset] == servo.dxl_id:
            servo.write(address, params[offset + 1 : offset + 1 + length], now)


def _group_read_request(dxl_id: int, inst: int, params: bytes) -> tuple[int | None, int, int]:
    """(reply slot of ``dxl_id``, or None if not listed; address; length) of a SYNC_READ or BULK_READ."""
    if inst == INST_SYNC_READ:
        listed = list(params[4:])
        if len(params) < 4 or dxl_id not in listed:
            return None, 0, 0
        return listed.index(dxl_id), _u16(params, 0), _u16(params, 2)
    for slot, offset in enumerate(range(0, len(params) - 4, 5)):
        if params[offset] == dxl_id:
            return slot, _u16(params, offset + 1), _u16(params, offset + 3)
    return None, 0, 0


def _clear(servo: _Servo, params: bytes) -> int:
    """CLEAR with option 0x01 (fixed key 44 58 4C 22): reset the multi-turn count of a stopped servo."""
    if params != b"\x01\x44\x58\x4c\x22":
        return ERR_DATA_RANGE
    if servo.velocity != 0.0:
        return ERR_RESULT_FAIL  # the manual allows CLEAR only while the servo is stopped
    servo.wrap_to_one_turn()
    return 0


def _u16(data: bytes, offset: int) -> int:
    return data[offset] | data[offset + 1] << 8

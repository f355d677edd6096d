"""One emulated MX-28(2.0) servo (no ROS): its control-table state and how it executes Protocol 2.0
instructions.

The register semantics (access, ranges, EEPROM lock, bus watchdog, shutdown, multi-turn reset)
follow the ROBOTIS e-Manual MX-28(2.0) page; behaviour the manual leaves open is marked
"assumption". The shaft's motion is not modelled here: with a
:class:`hsa_core.model.actuation.ServoModel` the shaft follows its goal by that model (the emulator
used alone, by the driver's tests); with ``model=None`` it is driven from outside (sim_node: the
shafts of :class:`hsa_core.sim.world.World`).
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

from hsa_core.model.actuation import ServoModel
from hsa_sim_node.control_table import (
    ADDR_BAUD_RATE,
    ADDR_BUS_WATCHDOG,
    ADDR_FIRMWARE,
    ADDR_GOAL_POSITION,
    ADDR_HARDWARE_ERROR,
    ADDR_ID,
    ADDR_MAX_POSITION,
    ADDR_MIN_POSITION,
    ADDR_MOVING,
    ADDR_MOVING_THRESHOLD,
    ADDR_OPERATING_MODE,
    ADDR_PRESENT_POSITION,
    ADDR_PRESENT_VELOCITY,
    ADDR_REALTIME_TICK,
    ADDR_SHUTDOWN,
    ADDR_STATUS_RETURN_LEVEL,
    ADDR_TORQUE_ENABLE,
    EEPROM_END,
    EXTENDED_GOAL_LIMIT,
    GOALS,
    ITEMS,
    OWNER,
    TABLE_SIZE,
    TICKS_PER_REV,
    VELOCITY_UNIT_RPM,
    Item,
)
from hsa_sim_node.protocol import (
    BROADCAST_ID,
    ERR_ACCESS,
    ERR_DATA_LENGTH,
    ERR_DATA_LIMIT,
    ERR_DATA_RANGE,
    ERR_INSTRUCTION,
    ERR_RESULT_FAIL,
    ERRBIT_ALERT,
    INST_BULK_READ,
    INST_CLEAR,
    INST_PING,
    INST_READ,
    INST_REBOOT,
    INST_SYNC_READ,
    INST_SYNC_WRITE,
    INST_WRITE,
    Packet,
    u16,
)


class RegisterWrite(NamedTuple):
    """One control-table item changed by a WRITE or SYNC_WRITE, stamped when the emulator executed
    the packet."""

    time: float  # time.monotonic() (CLOCK_MONOTONIC, comparable between processes of one machine)
    dxl_id: int
    address: int
    value: int


class Servo:
    """Control table and shaft state of one emulated MX-28(2.0)."""

    def __init__(
        self, dxl_id: int, baud_code: int, ticks: int, model: ServoModel | None, now: float
    ) -> None:
        self.table = bytearray(TABLE_SIZE)
        for item in ITEMS.values():
            self.put(item.address, item.default)
        self.put(ADDR_ID, dxl_id)
        self.put(ADDR_BAUD_RATE, baud_code)
        self.position = float(ticks)
        self.velocity = 0.0
        # assumption: at power-on the goal equals the present position
        self.put(ADDR_GOAL_POSITION, ticks)
        self.model = model
        self.responsive = True
        self.updated = now
        self.last_instruction = now
        # the emulator's write log, if it keeps one
        self.journal: deque[RegisterWrite] | None = None

    @property
    def dxl_id(self) -> int:
        """Current ID (the ID item can be written over the bus)."""
        return self.table[ADDR_ID]

    @property
    def torque_on(self) -> bool:
        """Torque Enable (64) is on."""
        return self.table[ADDR_TORQUE_ENABLE] == 1

    def get(self, address: int) -> int:
        """Value of the item at ``address`` (with its size and signedness)."""
        item = ITEMS[address]
        return int.from_bytes(
            self.table[address : address + item.size], "little", signed=item.signed
        )

    def put(self, address: int, value: int) -> None:
        """Store ``value`` in the item at ``address`` without any access check."""
        item = ITEMS[address]
        self.table[address : address + item.size] = int(value).to_bytes(
            item.size, "little", signed=item.signed
        )

    def error_byte(self, error: int) -> int:
        """Status error field: the error number plus the alert bit while a hardware error is
        latched."""
        return error | (ERRBIT_ALERT if self.table[ADDR_HARDWARE_ERROR] else 0)

    def advance(self, now: float) -> None:
        """Move the shaft to time ``now``, tripping the bus watchdog at its exact expiry time if
        due."""
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
            self.position, self.velocity = self.model.step(
                self.position, self.get(ADDR_GOAL_POSITION), dt
            )
        else:
            self.velocity = 0.0

    def refresh(self, now: float) -> None:
        """Update the computed registers (present position/velocity, moving, realtime tick) for a
        read at ``now``."""
        self.advance(now)
        self.put(ADDR_PRESENT_POSITION, max(-(2**31), min(2**31 - 1, round(self.position))))
        velocity = round(self.velocity * 60.0 / TICKS_PER_REV / VELOCITY_UNIT_RPM)
        self.put(ADDR_PRESENT_VELOCITY, velocity)
        self.put(ADDR_MOVING, int(abs(velocity) > self.get(ADDR_MOVING_THRESHOLD)))
        self.put(ADDR_REALTIME_TICK, int(now * 1000) % 32768)

    def wrap_to_one_turn(self) -> None:
        """Reset the multi-turn count: present (and goal) move into one absolute rotation, the shaft
        stays put."""
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
        """WRITE semantics, all-or-nothing: returns the error number (0 when applied, then journaled
        at ``now``)."""
        staged: list[tuple[Item, int]] = []
        pos, end = address, address + len(data)
        if not data:
            return ERR_DATA_LENGTH
        while pos < end:
            item = ITEMS.get(pos)
            if item is None:
                return ERR_DATA_LENGTH if pos in OWNER else ERR_ACCESS
            if pos + item.size > end:
                return ERR_DATA_LENGTH
            if not item.writable or (item.address < EEPROM_END and self.torque_on):
                return ERR_ACCESS
            value = int.from_bytes(
                data[pos - address : pos - address + item.size], "little", signed=item.signed
            )
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

    def _check(self, item: Item, value: int) -> int:
        if item.valid is not None and value not in item.valid:
            return ERR_DATA_RANGE
        if item.address in GOALS and self.get(ADDR_BUS_WATCHDOG) == -1:
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

    def _apply(self, item: Item, value: int) -> None:
        self.put(item.address, value)
        position_mode = self.get(ADDR_OPERATING_MODE) == 3
        if item.address == ADDR_OPERATING_MODE and position_mode:
            self.wrap_to_one_turn()
        if item.address == ADDR_TORQUE_ENABLE and value == 1 and position_mode:
            self.wrap_to_one_turn()

    def reboot(self) -> None:
        """REBOOT: RAM back to defaults, errors cleared, torque off, present position within one
        turn."""
        for item in ITEMS.values():
            if (
                item.address >= EEPROM_END and item.writable
            ) or item.address == ADDR_HARDWARE_ERROR:
                self.put(item.address, item.default)
        self.wrap_to_one_turn()
        self.put(ADDR_GOAL_POSITION, round(self.position))
        self.velocity = 0.0

    def set_hardware_error(self, bits: int) -> None:
        """Latch hardware error bits; bits enabled in Shutdown(63) switch the torque off."""
        self.put(ADDR_HARDWARE_ERROR, bits)
        if self._shut_down():
            self.put(ADDR_TORQUE_ENABLE, 0)


def execute(servo: Servo, packet: Packet, now: float) -> list[tuple[int, int, bytes]]:
    """One servo's part of an instruction packet: (reply slot, status error field, data) for each
    status it owes."""
    inst, params, unicast = packet.instruction, packet.params, packet.dxl_id == servo.dxl_id
    level = servo.table[ADDR_STATUS_RETURN_LEVEL]
    if not unicast and packet.dxl_id != BROADCAST_ID:
        return []
    if inst == INST_PING:  # answered at every Status Return Level
        return [
            (
                servo.dxl_id,
                servo.error_byte(0),
                bytes(servo.table[0:2] + servo.table[ADDR_FIRMWARE:7]),
            )
        ]
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
        error = (
            servo.write(u16(params, 0), params[2:], now) if len(params) >= 3 else ERR_INSTRUCTION
        )
        return [(0, servo.error_byte(error), b"")] if unicast and level == 2 else []
    if not unicast:
        return []  # READ, REBOOT, CLEAR and unknown instructions get no broadcast reply
    if inst == INST_READ:
        if len(params) != 4:
            return [(0, servo.error_byte(ERR_INSTRUCTION), b"")] if level >= 1 else []
        error, data = servo.read(u16(params, 0), u16(params, 2), now)
        return [(0, servo.error_byte(error), data)] if level >= 1 else []
    if inst == INST_REBOOT:
        field = servo.error_byte(0)  # the status leaves before the reboot clears the error
        servo.reboot()
        return [(0, field, b"")] if level == 2 else []
    error = _clear(servo, params) if inst == INST_CLEAR else ERR_INSTRUCTION
    return [(0, servo.error_byte(error), b"")] if level == 2 else []


def _sync_write(servo: Servo, params: bytes, now: float) -> None:
    """Apply ``servo``'s slice of a SYNC_WRITE (no status is ever returned)."""
    if len(params) < 4:
        return
    address, length = u16(params, 0), u16(params, 2)
    for offset in range(4, len(params) - length, length + 1):
        if params[offset] == servo.dxl_id:
            servo.write(address, params[offset + 1 : offset + 1 + length], now)


def _group_read_request(dxl_id: int, inst: int, params: bytes) -> tuple[int | None, int, int]:
    """(reply slot of ``dxl_id``, or None if not listed; address; length) of a SYNC_READ or
    BULK_READ."""
    if inst == INST_SYNC_READ:
        listed = list(params[4:])
        if len(params) < 4 or dxl_id not in listed:
            return None, 0, 0
        return listed.index(dxl_id), u16(params, 0), u16(params, 2)
    for slot, offset in enumerate(range(0, len(params) - 4, 5)):
        if params[offset] == dxl_id:
            return slot, u16(params, offset + 1), u16(params, offset + 3)
    return None, 0, 0


def _clear(servo: Servo, params: bytes) -> int:
    """CLEAR with option 0x01 (fixed key 44 58 4C 22): reset the multi-turn count of a stopped
    servo."""
    if params != b"\x01\x44\x58\x4c\x22":
        return ERR_DATA_RANGE
    if servo.velocity != 0.0:
        return ERR_RESULT_FAIL  # the manual allows CLEAR only while the servo is stopped
    servo.wrap_to_one_turn()
    return 0

"""Emulated bus of MX-28(2.0) Dynamixel servos speaking Protocol 2.0 on a pseudo-terminal (no ROS).

The real ``dynamixel_sdk`` (or any Protocol 2.0 client) opens ``emulator.port`` like a U2D2 device.
This module is the bus: the pseudo-terminal, its serving thread, the simulator's and tests' API and
fault injection, traffic counters. The packet codec is :mod:`hsa_sim_node.protocol`, the register
table :mod:`hsa_sim_node.control_table`, one servo's registers and instruction semantics
:mod:`hsa_sim_node.servo`; their public names are re-exported here. Protocol facts follow the
ROBOTIS e-Manual (Protocol 2.0 and MX-28(2.0) pages); behaviour the manual leaves open is marked
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

from hsa_core.model.actuation import ServoModel

# Re-exported: the names tests, benchmarks and the node import from this module (one import for the
# whole bus).
from hsa_sim_node.control_table import (  # noqa: E402,F401,I001
    ADDR_BAUD_RATE,
    ADDR_GOAL_POSITION,
    ADDR_HARDWARE_ERROR,
    ADDR_PRESENT_POSITION,
    ADDR_RETURN_DELAY,
    ADDR_TORQUE_ENABLE,
    BAUD_RATE_CODES,
    COMPUTED,
    HW_ELECTRICAL_SHOCK,
    HW_INPUT_VOLTAGE,
    HW_MOTOR_ENCODER,
    HW_OVERHEATING,
    HW_OVERLOAD,
    SPEED_CODES,
)
from hsa_sim_node.protocol import (  # noqa: E402,F401
    BROADCAST_ID,
    ERR_ACCESS,
    ERR_CRC,
    ERR_DATA_LENGTH,
    ERR_DATA_LIMIT,
    ERR_DATA_RANGE,
    ERR_INSTRUCTION,
    ERR_RESULT_FAIL,
    ERRBIT_ALERT,
    HEADER,
    INST_BULK_READ,
    INST_CLEAR,
    INST_PING,
    INST_READ,
    INST_REBOOT,
    INST_STATUS,
    INST_SYNC_READ,
    INST_SYNC_WRITE,
    INST_WRITE,
    MAX_ID,
    Packet,
    PacketReader,
    crc16,
    encode_packet,
    stuff,
    unstuff,
)
from hsa_sim_node.servo import RegisterWrite, Servo, execute

# an incomplete packet older than this is discarded (the wire went quiet mid-packet)
_STALE_INPUT_S = 0.1
_POLL_S = 0.1  # select timeout of the serving thread; it only bounds how long stale input lingers


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


class MX28Emulator:
    """A pseudo-terminal bus of N MX-28(2.0) servos served by a background thread; also the
    simulator's servo API.

    Goal Position is stored while torque is off but only moves the shaft with torque on (a servo
    whose goal was written with torque off moves to it when torque is switched on, as real ones do).
    With ``model=None`` the shaft is driven externally through :meth:`set_present_ticks`.
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
            raise ValueError(
                f"baudrate {baudrate} is not an MX-28(2.0) rate {sorted(BAUD_RATE_CODES)}"
            )
        ids = tuple(ids)
        if not ids or len(set(ids)) != len(ids) or not all(0 <= i <= MAX_ID for i in ids):
            raise ValueError(f"ids must be unique integers in 0..{MAX_ID}, got {ids}")
        now = time.monotonic()
        ticks = dict(initial_ticks or {})
        self._servos = [
            Servo(i, BAUD_RATE_CODES[baudrate], ticks.get(i, 2048), model, now) for i in ids
        ]
        self._journal = _Journal(write_log_size)
        # the serving thread is between reading bytes and finishing their packets
        self._busy = False
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
        """The pseudo-terminal exists and is served (between start/replug and unplug/stop)."""
        return self._thread is not None

    def start(self) -> MX28Emulator:
        """Create the pseudo-terminal, point the symlink at it and start serving."""
        if self._thread is None:
            self._plug()
        return self

    def stop(self) -> None:
        """Stop serving, close the pseudo-terminal and remove the symlink (and its directory if we
        made it)."""
        self.unplug()
        if self._own_dir is not None:
            shutil.rmtree(self._own_dir, ignore_errors=True)

    def __enter__(self) -> MX28Emulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def unplug(self) -> None:
        """Make the device disappear: the driver's open port starts failing with EIO and the symlink
        is removed."""
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
        """Plug the bus back in on a fresh pseudo-terminal; the symlink now points at it (servo
        state is kept)."""
        if self._thread is None:
            self._plug()

    def _plug(self) -> None:
        master, slave = os.openpty()
        # before any client opens it, or the line discipline mangles the first bytes
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave, self._wake = master, slave, os.pipe()
        staging = self._link.with_name(self._link.name + ".new")
        staging.unlink(missing_ok=True)
        os.symlink(os.ttyname(slave), staging)
        os.replace(staging, self._link)
        self._thread = threading.Thread(
            target=self._serve, args=(master, self._wake[0]), name="mx28-emulator"
        )
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

    def set_present_ticks(
        self, dxl_id: int, ticks: float, velocity_ticks_per_s: float = 0.0
    ) -> None:
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
        """Value of the control-table item starting at ``address`` (size and sign from the
        MX-28(2.0) table)."""
        with self._lock:
            servo = self._servo(dxl_id)
            servo.refresh(time.monotonic())
            return servo.get(address)

    def poke(self, dxl_id: int, address: int, value: int) -> None:
        """Overwrite an item bypassing access rules (temperature, voltage, load, model number...)
        for tests."""
        if address in COMPUTED:
            raise ValueError(
                f"address {address} is computed from the shaft state; use set_present_ticks"
            )
        with self._lock:
            self._servo(dxl_id).put(address, value)

    # ---------------------------------------------------------------- fault injection
    def set_responsive(self, dxl_id: int, responsive: bool) -> None:
        """A non-responsive servo still executes instructions but never sends a status packet (like
        a cut wire)."""
        with self._lock:
            self._servo(dxl_id).responsive = responsive

    def set_hardware_error(self, dxl_id: int, bits: int) -> None:
        """Latch Hardware Error Status bits (e.g. HW_OVERLOAD); statuses then carry the alert bit,
        torque may trip."""
        with self._lock:
            self._servo(dxl_id).set_hardware_error(bits)

    def corrupt_next_statuses(self, count: int = 1) -> None:
        """Send the next ``count`` status packets with a wrong CRC."""
        with self._lock:
            self._corrupt_statuses += count

    def writes(self, address: int | None = None, since: float = -math.inf) -> list[RegisterWrite]:
        """Logged register writes (all, or of the item at ``address``) executed at or after
        ``since``, oldest first.

        The log keeps the newest ``write_log_size`` entries.
        """
        with self._lock:
            return [
                w
                for w in self._journal
                if w.time >= since and (address is None or w.address == address)
            ]

    def idle(self) -> bool:
        """No byte the client wrote is left unexecuted (the simulator's check that a write has
        landed): nothing unread on the line and the serving thread not between a read and the end of
        its packets."""
        if self._busy or self._master is None:
            return not self._busy
        readable, _, _ = select.select([self._master], [], [], 0.0)
        return not readable and not self._busy

    def drain_writes(self, address: int) -> list[RegisterWrite]:
        """Writes of the item at ``address`` logged since the previous call, oldest first (the
        simulator's feed)."""
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
            return EmulatorStats(
                **{f.name: getattr(self._stats, f.name) for f in fields(EmulatorStats)}
            )

    # ---------------------------------------------------------------- serving
    def _servo(self, dxl_id: int) -> Servo:
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
                        # nobody reads the port and its buffer is full: the bytes are lost, as on a
                        # wire
                        pass
            self._busy = False

    def _handle(self, packet: Packet, master: int) -> list[tuple[float, bytes]]:
        """Execute one instruction packet; returns (return delay, status packet) pairs to send in
        order."""
        with self._lock:
            now = time.monotonic()
            replies: list[tuple[int, Servo, int, bytes]] = []
            if not packet.crc_ok:
                self._stats.crc_errors += 1
                replies = [
                    (0, s, s.error_byte(ERR_CRC), b"")
                    for s in self._servos
                    if s.dxl_id == packet.dxl_id
                ]
            else:
                self._count(packet)
                code = self._line_baud_code(master)
                for servo in self._servos:
                    servo.advance(now)
                    servo.last_instruction = now
                deaf = [
                    s for s in self._servos if code is not None and code != s.table[ADDR_BAUD_RATE]
                ]
                # those servos only see garbage at the wrong rate
                self._stats.baud_mismatches += bool(deaf)
                for servo in self._servos:
                    if servo not in deaf:
                        replies += [
                            (slot, servo, err, data)
                            for slot, err, data in execute(servo, packet, now)
                        ]
            # stable: sync-read order, or ID order for a broadcast ping
            replies.sort(key=lambda reply: reply[0])
            return [
                self._status(servo, err, data)
                for _, servo, err, data in replies
                if servo.responsive
            ]

    def _count(self, packet: Packet) -> None:
        self._stats.packets_received += 1
        self._stats.sync_writes += packet.instruction == INST_SYNC_WRITE
        self._stats.sync_reads += packet.instruction == INST_SYNC_READ

    def _line_baud_code(self, master: int) -> int | None:
        """Baud Rate(8) code of the line speed the client set (-1: not an MX-28 rate), or None when
        not checked."""
        if not self._check_baud:
            return None
        return SPEED_CODES.get(termios.tcgetattr(master)[5], -1)

    def _status(self, servo: Servo, error_field: int, params: bytes) -> tuple[float, bytes]:
        """A status packet from ``servo`` and the Return Delay Time (2 µs units) to wait before
        sending it."""
        payload = encode_packet(servo.dxl_id, INST_STATUS, bytes([error_field]) + params)
        if self._corrupt_statuses:
            self._corrupt_statuses -= 1
            payload = payload[:-2] + bytes([payload[-2] ^ 0xFF, payload[-1]])
        self._stats.statuses_sent += 1
        return servo.table[ADDR_RETURN_DELAY] * 2e-6, payload

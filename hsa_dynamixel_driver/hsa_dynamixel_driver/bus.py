"""ROS-free access to a Protocol 2.0 bus of MX-28(2.0) servos through ``dynamixel_sdk``, in raw
ticks.

One GroupSyncWrite (goals) and one GroupSyncRead (present positions) per control cycle. Every
failure surfaces as a :class:`BusError` subclass naming the servo and carrying the SDK's own
message; nothing here converts units.
"""

from __future__ import annotations

import math
import os
import select
import termios
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import serial
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

# MX-28(2.0) control table (ROBOTIS e-Manual).
ADDR_MODEL_NUMBER = 0
ADDR_RETURN_DELAY_TIME = 9
ADDR_OPERATING_MODE = 11
ADDR_TORQUE_ENABLE = 64
ADDR_HARDWARE_ERROR_STATUS = 70
ADDR_GOAL_POSITION = 116
ADDR_PRESENT_VELOCITY = 128  # followed by Present Position: one 8-byte sync read gets both
ADDR_PRESENT_POSITION = 132
MX28_MODEL_NUMBER = 30
POSITION_MODE = 3
EXTENDED_POSITION_MODE = 4
# ±256 rev: larger goals are refused by the servo, silently in a sync write
EXTENDED_GOAL_LIMIT = 1_048_575
TICKS_PER_REV = 4096
VELOCITY_UNIT_RAD_S = 0.229 * 2.0 * math.pi / 60.0  # Present Velocity (128) unit: 0.229 rev/min
ERRBIT_ALERT = 0x80
HARDWARE_ERROR_BITS = {
    0x01: "input voltage",
    0x04: "overheating",
    0x08: "motor encoder",
    0x10: "electrical shock",
    0x20: "overload",
}
# PortHandler.setBaudRate accepts exactly these rates.
SDK_BAUDRATES = (
    9600,
    19200,
    38400,
    57600,
    115200,
    230400,
    460800,
    500000,
    576000,
    921600,
    1_000_000,
    1_152_000,
    2_000_000,
    2_500_000,
    3_000_000,
    3_500_000,
    4_000_000,
)
LATENCY_TIMER_ROOT = "/sys/bus/usb-serial/devices"

_T = TypeVar("_T")


class BusError(Exception):
    """A bus operation failed; ``dxl_id`` is the servo concerned (None: the whole bus) and the
    message says why."""

    def __init__(
        self,
        operation: str,
        dxl_id: int | None,
        detail: str,
        *,
        comm_result: int | None = None,
        packet_error: int | None = None,
    ) -> None:
        where = f"ID {dxl_id}" if dxl_id is not None else "bus"
        super().__init__(f"{operation} on {where}: {detail}")
        self.operation = operation
        self.dxl_id = dxl_id
        self.comm_result = comm_result
        self.packet_error = packet_error


class PortError(BusError):
    """The serial device cannot be opened or stopped working (unplugged): reconnect."""


class CommError(BusError):
    """No valid status packet came back (timeout or corrupt); ``comm_result`` is the SDK's COMM_*
    code."""


class ServoStatusError(BusError):
    """The servo answered with an error number (``packet_error``, e.g. 7 = access error)."""


@dataclass(frozen=True)
class PositionReading:
    """Present positions (ticks) and velocities (raw, VELOCITY_UNIT_RAD_S) of one sync read;
    ``alerts`` are IDs whose status carried the hardware-error bit."""

    ticks: dict[int, int]
    alerts: frozenset[int]
    velocities: dict[int, int]


@dataclass(frozen=True)
class LatencyTimer:
    """FTDI USB latency timer of the port's device; ``value_ms`` is None when it has none (pty,
    non-FTDI adapter)."""

    device: str
    value_ms: int | None

    @property
    def slow(self) -> bool:
        """True when reads can wait longer than 1 ms for the adapter to flush."""
        return self.value_ms is not None and self.value_ms > 1

    def describe(self) -> str:
        """One line for a log or a diagnostics message."""
        if self.value_ms is None:
            return f"{self.device}: no latency_timer (not an FTDI USB-serial device); check skipped"
        if self.slow:
            return (
                f"{self.device}: latency_timer is {self.value_ms} ms, every read may wait that "
                "long; set it to 1 (echo 1 > "
                f"{LATENCY_TIMER_ROOT}/{Path(self.device).name}/latency_timer, or a udev rule)"
            )
        return f"{self.device}: latency_timer is {self.value_ms} ms"


def describe_hardware_error(bits: int) -> str:
    """Human-readable Hardware Error Status (70), e.g. 'overload, overheating'."""
    names = [name for bit, name in HARDWARE_ERROR_BITS.items() if bits & bit]
    return ", ".join(names) if names else "none"


class _WaitingPortHandler(PortHandler):
    """PortHandler that sleeps in select() until bytes arrive or the packet deadline passes, instead
    of busy-polling; ``min_timeout_ms`` raises the SDK's per-packet timeout (≈ 34 ms) to at least
    that much."""

    min_timeout_ms = 0.0

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802 (SDK method name)
        super().setPacketTimeout(packet_length)
        self.packet_timeout = max(self.packet_timeout, self.min_timeout_ms)

    def setPacketTimeoutMillis(self, msec: float) -> None:  # noqa: N802 (SDK method name)
        super().setPacketTimeoutMillis(msec)
        self.packet_timeout = max(self.packet_timeout, self.min_timeout_ms)

    def readPort(self, length: int) -> bytes:  # noqa: N802 (SDK method name)
        if length > 0:
            remaining_ms = self.packet_timeout - self.getTimeSinceStart()
            if remaining_ms > 0.0:
                select.select([self.ser.fileno()], [], [], remaining_ms / 1000.0)
        return super().readPort(length)


class DynamixelBus:
    """A Protocol 2.0 bus of MX-28(2.0) servos: open/ping, configure, sync read/write in ticks,
    torque, recovery.

    Thread-safe (one lock serialises packets). The context manager switches torque off (best effort)
    and closes.
    """

    def __init__(
        self,
        port: str,
        baudrate: int,
        ids: Sequence[int],
        *,
        model_number: int = MX28_MODEL_NUMBER,
        min_packet_timeout_ms: float = 0.0,
    ) -> None:
        if baudrate not in SDK_BAUDRATES:
            raise ValueError(
                f"baudrate {baudrate} is not one the Dynamixel SDK supports: {SDK_BAUDRATES}"
            )
        ids = tuple(int(i) for i in ids)
        if not ids or len(set(ids)) != len(ids) or not all(0 <= i <= 252 for i in ids):
            raise ValueError(f"ids must be unique integers in 0..252, got {ids}")
        self._port_name = port
        self._baudrate = baudrate
        self._ids = ids
        self._model_number = model_number
        self._ph = PacketHandler(2.0)
        self._port: _WaitingPortHandler | None = None
        self._lock = threading.RLock()
        # assumed until configure() sets it; only bounds goal checks
        self._mode = EXTENDED_POSITION_MODE
        self._min_timeout_ms = float(min_packet_timeout_ms)

    @property
    def ids(self) -> tuple[int, ...]:
        return self._ids

    @property
    def port_name(self) -> str:
        return self._port_name

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def __enter__(self) -> DynamixelBus:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disable_torque()
        self.close()

    # ---------------------------------------------------------------- connection
    def open(self) -> None:
        """Open the port at the configured baud rate and ping every servo (model number checked)."""
        with self._lock:
            if self._port is not None:
                raise RuntimeError(f"{self._port_name} is already open")
            port = _WaitingPortHandler(self._port_name)
            port.min_timeout_ms = self._min_timeout_ms
            try:
                opened = port.setBaudRate(self._baudrate)
            except (serial.SerialException, OSError, termios.error) as exc:
                raise PortError("open", None, f"cannot open {self._port_name}: {exc}") from exc
            if not opened:
                raise PortError(
                    "open", None, f"cannot open {self._port_name} at {self._baudrate} baud"
                )
            self._port = port
            try:
                self.ping()
            except BusError:
                self.close()
                raise

    def close(self) -> None:
        """Close the port; never raises (the device may already be gone)."""
        with self._lock:
            if self._port is not None:
                try:
                    self._port.closePort()
                except (serial.SerialException, OSError, termios.error):
                    pass
                self._port = None

    def reconnect(self) -> None:
        """Close and reopen the port (e.g. after an unplug) and ping every servo; raises PortError
        while absent.

        Servos that lost power come back with RAM defaults (torque off); configure() again if
        needed.
        """
        with self._lock:
            self.close()
            self.open()

    def ping(self) -> None:
        """Ping every servo and check its model number."""
        with self._lock:
            for dxl_id in self._ids:
                model, result, error = self._io(
                    "ping", lambda i=dxl_id: self._ph.ping(self._port, i)
                )
                self._check("ping", dxl_id, result, error)
                if model != self._model_number:
                    raise BusError(
                        "ping", dxl_id, f"model number {model}, expected {self._model_number}"
                    )

    # ---------------------------------------------------------------- configuration and torque
    def configure(
        self,
        *,
        return_delay: int = 0,
        operating_mode: int = EXTENDED_POSITION_MODE,
        torque_on: bool = False,
    ) -> None:
        """Torque off, then Return Delay Time and Operating Mode (EEPROM, written only if
        different), then torque on if asked (holding the present position)."""
        if not 0 <= return_delay <= 254:
            raise ValueError(f"return_delay must be in 0..254 (2 µs units), got {return_delay}")
        if operating_mode not in (POSITION_MODE, EXTENDED_POSITION_MODE):
            raise ValueError(
                f"operating_mode must be {POSITION_MODE} or {EXTENDED_POSITION_MODE}: "
                f"{operating_mode}"
            )
        with self._lock:
            for dxl_id in self._ids:
                self.write_register(dxl_id, ADDR_TORQUE_ENABLE, 1, 0)
                for address, value in (
                    (ADDR_RETURN_DELAY_TIME, return_delay),
                    (ADDR_OPERATING_MODE, operating_mode),
                ):
                    if self.read_register(dxl_id, address, 1) != value:
                        self.write_register(dxl_id, address, 1, value)
            self._mode = operating_mode
            if torque_on:
                self.enable_torque()

    def enable_torque(self) -> None:
        """Torque on for every servo, after setting each goal to its present position so nothing
        jumps."""
        with self._lock:
            present = self.read_positions().ticks
            if self._mode == POSITION_MODE:  # torque-on reduces the present position to one turn
                present = {dxl_id: ticks % TICKS_PER_REV for dxl_id, ticks in present.items()}
            self.write_goals(present)
            for dxl_id in self._ids:
                self.write_register(dxl_id, ADDR_TORQUE_ENABLE, 1, 1)

    def disable_torque(self, *, verify: bool = True) -> frozenset[int]:
        """Best-effort torque off, for shutdown and error paths: never raises; returns the IDs not
        confirmed off.

        One sync write reaches every responsive servo at once; the optional check then reads each
        servo back.
        """
        if not self._lock.acquire(timeout=1.0):
            return frozenset(self._ids)
        try:
            if self._port is None:
                return frozenset(self._ids)
            # A transaction interrupted by an exception (e.g. KeyboardInterrupt from a signal)
            # leaves the SDK's busy flag set and a partial status in the input buffer; either would
            # silently block this torque-off.
            self._port.is_using = False
            try:
                self._port.clearPort()
            except (serial.SerialException, OSError, termios.error):
                pass
            try:
                torque_off = GroupSyncWrite(self._port, self._ph, ADDR_TORQUE_ENABLE, 1)
                for dxl_id in self._ids:
                    torque_off.addParam(dxl_id, [0])
                self._io("disable_torque", torque_off.txPacket)
            except BusError:
                return frozenset(self._ids)
            if not verify:
                return frozenset()
            unconfirmed = set()
            for dxl_id in self._ids:
                try:
                    if self.read_register(dxl_id, ADDR_TORQUE_ENABLE, 1) != 0:
                        unconfirmed.add(dxl_id)
                except BusError:
                    unconfirmed.add(dxl_id)
            return frozenset(unconfirmed)
        finally:
            self._lock.release()

    def reboot(self, dxl_id: int) -> None:
        """REBOOT one servo (Protocol 2.0 instruction 0x08; clears a latched hardware error); it
        restarts with torque off and RAM defaults, and answers again once it has booted (see
        :meth:`wait_answering`).

        In extended position mode the present position comes back reduced to one turn (0..4095).
        """
        with self._lock:
            result, error = self._io("reboot", lambda: self._ph.reboot(self._port, dxl_id))
            self._check("reboot", dxl_id, result, error)

    def wait_answering(self, ids: Sequence[int], timeout: float) -> None:
        """Ping ``ids`` until each answers (a rebooting servo is silent while it boots), for at most
        ``timeout`` seconds of wall time (a bus-level wait, like the SDK's packet timeout); raises
        the last ping's error."""
        deadline = time.monotonic() + timeout
        with self._lock:
            for dxl_id in ids:
                while True:
                    model, result, error = self._io(
                        "ping", lambda i=dxl_id: self._ph.ping(self._port, i)
                    )
                    if result == COMM_SUCCESS or time.monotonic() >= deadline:
                        break
                    time.sleep(0.005)
                self._check("ping", dxl_id, result, error)
                if model != self._model_number:
                    raise BusError(
                        "ping", dxl_id, f"model number {model}, expected {self._model_number}"
                    )

    # ---------------------------------------------------------------- cyclic I/O
    def read_positions(self) -> PositionReading:
        """Present Velocity and Present Position of every servo with one Sync Read instruction
        (addresses 128-135).

        GroupSyncRead builds and sends the instruction; the statuses are collected with readRx
        because GroupSyncRead.rxPacket drops their error byte and with it the hardware-error alert.
        """
        data = self._group_read("read_positions", ADDR_PRESENT_VELOCITY, 8)
        ticks = {
            dxl_id: int.from_bytes(raw[4:], "little", signed=True)
            for dxl_id, (raw, _) in data.items()
        }
        velocities = {
            dxl_id: int.from_bytes(raw[:4], "little", signed=True)
            for dxl_id, (raw, _) in data.items()
        }
        alerts = frozenset(dxl_id for dxl_id, (_, error) in data.items() if error & ERRBIT_ALERT)
        return PositionReading(ticks, alerts, velocities)

    def write_goals(self, goals: Mapping[int, int]) -> None:
        """Goal Position (signed ticks) for some or all servos with one Sync Write instruction (no
        status returns)."""
        unknown = set(goals) - set(self._ids)
        if unknown or not goals:
            raise ValueError(f"goals must name some of the IDs {self._ids}, got {sorted(goals)}")
        limit = EXTENDED_GOAL_LIMIT
        allowed = (
            range(0, TICKS_PER_REV) if self._mode == POSITION_MODE else range(-limit, limit + 1)
        )
        for dxl_id, ticks in goals.items():
            if int(ticks) != ticks or int(ticks) not in allowed:
                raise ValueError(f"goal {ticks} for ID {dxl_id} is outside {allowed}")
        with self._lock:
            writer = GroupSyncWrite(self._port, self._ph, ADDR_GOAL_POSITION, 4)
            for dxl_id, ticks in goals.items():
                writer.addParam(dxl_id, list(int(ticks).to_bytes(4, "little", signed=True)))
            result = self._io("write_goals", writer.txPacket)
            if result != COMM_SUCCESS:
                raise CommError(
                    "write_goals", None, self._ph.getTxRxResult(result), comm_result=result
                )

    def read_hardware_errors(self) -> dict[int, int]:
        """Hardware Error Status (70) of every servo with one Sync Read (see
        describe_hardware_error)."""
        data = self._group_read("read_hardware_errors", ADDR_HARDWARE_ERROR_STATUS, 1)
        return {dxl_id: raw[0] for dxl_id, (raw, _) in data.items()}

    # ---------------------------------------------------------------- single registers
    def read_register(self, dxl_id: int, address: int, size: int, *, signed: bool = False) -> int:
        """Read a 1-, 2- or 4-byte control-table item of one servo."""
        if size not in (1, 2, 4):
            raise ValueError(f"size must be 1, 2 or 4, got {size}")
        with self._lock:
            data, result, error = self._io(
                "read_register", lambda: self._ph.readTxRx(self._port, dxl_id, address, size)
            )
            self._check(f"read_register({address})", dxl_id, result, error)
            return int.from_bytes(bytes(data[:size]), "little", signed=signed)

    def write_register(self, dxl_id: int, address: int, size: int, value: int) -> None:
        """Write a 1-, 2- or 4-byte control-table item of one servo and check its status."""
        if size not in (1, 2, 4):
            raise ValueError(f"size must be 1, 2 or 4, got {size}")
        raw = list(int(value).to_bytes(size, "little", signed=value < 0))
        with self._lock:
            result, error = self._io(
                "write_register", lambda: self._ph.writeTxRx(self._port, dxl_id, address, size, raw)
            )
            self._check(f"write_register({address})", dxl_id, result, error)

    def latency_timer(
        self, sysfs_root: str | os.PathLike[str] = LATENCY_TIMER_ROOT
    ) -> LatencyTimer:
        """The FTDI latency timer of this port (symlinks resolved); reports its absence instead of
        failing."""
        device = os.path.realpath(self._port_name)
        try:
            value = int(
                (Path(sysfs_root) / Path(device).name / "latency_timer").read_text().strip()
            )
        except (OSError, ValueError):
            value = None
        return LatencyTimer(device, value)

    # ---------------------------------------------------------------- internals
    def _group_read(self, operation: str, address: int, size: int) -> dict[int, tuple[bytes, int]]:
        """One Sync Read of ``size`` bytes at ``address``: {id: (data, status error field)}."""
        with self._lock:
            reader = GroupSyncRead(self._port, self._ph, address, size)
            for dxl_id in self._ids:
                reader.addParam(dxl_id)
            result = self._io(operation, reader.txPacket)
            if result != COMM_SUCCESS:
                raise CommError(operation, None, self._ph.getTxRxResult(result), comm_result=result)
            out = {}
            for dxl_id in self._ids:
                data, result, error = self._io(
                    operation, lambda i=dxl_id: self._ph.readRx(self._port, i, size)
                )
                self._check(operation, dxl_id, result, error)
                if len(data) != size:
                    raise CommError(
                        operation, dxl_id, f"status carried {len(data)} bytes, expected {size}"
                    )
                out[dxl_id] = (bytes(data), error)
            return out

    def _io(self, operation: str, call: Callable[[], _T]) -> _T:
        """Run one SDK call; a vanished device becomes PortError (and the SDK's busy flag is
        released)."""
        if self._port is None:
            raise PortError(operation, None, f"{self._port_name} is not open")
        try:
            return call()
        except (serial.SerialException, OSError, termios.error) as exc:
            self._port.is_using = False
            raise PortError(
                operation, None, f"{self._port_name} failed ({exc}); device unplugged?"
            ) from exc

    def _check(self, operation: str, dxl_id: int, result: int, error: int) -> None:
        """Raise for a failed transaction or an error number; the alert bit alone is not a
        failure."""
        if result != COMM_SUCCESS:
            raise CommError(operation, dxl_id, self._ph.getTxRxResult(result), comm_result=result)
        if error & ~ERRBIT_ALERT:
            raise ServoStatusError(
                operation,
                dxl_id,
                self._ph.getRxPacketError(error & ~ERRBIT_ALERT),
                packet_error=error & ~ERRBIT_ALERT,
            )

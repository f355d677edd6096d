"""The MX-28(2.0) control table (no ROS): every item's address, size, default, access and accepted
values.

Source: ROBOTIS e-Manual, MX-28(2.0) page, "Control Table" (EEPROM area: addresses < 64; RAM area:
64 and up). Indirect addresses/data are not emulated.

The driver names some of these addresses again in
``hsa_dynamixel_driver/hsa_dynamixel_driver/bus.py``. That duplication is deliberate: this table is
the emulator's own, independent transcription of the e-Manual, so the emulator is an oracle of the
real servo — a wrong address in the driver is refused or answered with the wrong item by the
emulator (and caught by the tests) instead of being shared by both sides. Do not import one from the
other.
"""

from __future__ import annotations

import termios
from dataclasses import dataclass

from hsa_sim_node.protocol import MAX_ID

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
VELOCITY_UNIT_RPM = 0.229  # one unit of Present Velocity (128) [rev/min]
BAUD_RATE_CODES = {
    9600: 0,
    57600: 1,
    115200: 2,
    1_000_000: 3,
    2_000_000: 4,
    3_000_000: 5,
    4_000_000: 6,
    4_500_000: 7,
}
# termios speed constant -> Baud Rate(8) code, for the rates this platform's termios knows.
SPEED_CODES = {
    getattr(termios, f"B{rate}"): code
    for rate, code in BAUD_RATE_CODES.items()
    if hasattr(termios, f"B{rate}")
}


@dataclass(frozen=True)
class Item:
    """One control-table entry; ``valid`` lists accepted write values (None: anything that fits in
    ``size`` bytes)."""

    address: int
    size: int
    default: int = 0
    writable: bool = True
    signed: bool = False
    valid: range | frozenset[int] | None = None


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

ITEMS = {
    item.address: item
    for item in (
        Item(ADDR_MODEL_NUMBER, 2, MX28_MODEL_NUMBER, writable=False),
        Item(2, 4, 0, writable=False),  # Model Information
        Item(ADDR_FIRMWARE, 1, MX28_FIRMWARE, writable=False),
        Item(ADDR_ID, 1, 1, valid=range(0, MAX_ID + 1)),
        Item(ADDR_BAUD_RATE, 1, 1, valid=range(0, 8)),
        Item(ADDR_RETURN_DELAY, 1, 250, valid=range(0, 255)),
        Item(10, 1, 0),  # Drive Mode
        Item(ADDR_OPERATING_MODE, 1, 3, valid=frozenset({1, 3, 4, 16})),
        Item(12, 1, 255),  # Secondary (Shadow) ID
        Item(13, 1, 2, valid=range(1, 3)),  # Protocol Version
        Item(20, 4, 0, signed=True),  # Homing Offset (stored, not applied)
        Item(ADDR_MOVING_THRESHOLD, 4, 10, valid=range(0, 1024)),
        Item(31, 1, 80),  # Temperature Limit
        Item(32, 2, 160),  # Max Voltage Limit
        Item(34, 2, 95),  # Min Voltage Limit
        Item(36, 2, 885),  # PWM Limit
        Item(40, 4, 32767),  # Acceleration Limit
        Item(44, 4, 380),  # Velocity Limit
        Item(ADDR_MAX_POSITION, 4, TICKS_PER_REV - 1, valid=range(0, TICKS_PER_REV)),
        Item(ADDR_MIN_POSITION, 4, 0, valid=range(0, TICKS_PER_REV)),
        Item(ADDR_SHUTDOWN, 1, HW_OVERHEATING | HW_ELECTRICAL_SHOCK | HW_OVERLOAD),
        Item(ADDR_TORQUE_ENABLE, 1, 0, valid=range(0, 2)),
        Item(65, 1, 0, valid=range(0, 2)),  # LED
        Item(ADDR_STATUS_RETURN_LEVEL, 1, 2, valid=range(0, 3)),
        Item(69, 1, 0, writable=False),  # Registered Instruction
        Item(ADDR_HARDWARE_ERROR, 1, 0, writable=False),
        Item(76, 2, 1920),  # Velocity I Gain
        Item(78, 2, 100),  # Velocity P Gain
        Item(80, 2, 0),  # Position D Gain
        Item(82, 2, 0),  # Position I Gain
        Item(84, 2, 850),  # Position P Gain
        Item(88, 2, 0),  # Feedforward 2nd Gain
        Item(90, 2, 0),  # Feedforward 1st Gain
        Item(ADDR_BUS_WATCHDOG, 1, 0, signed=True, valid=range(0, 128)),
        Item(ADDR_GOAL_PWM, 2, 885, signed=True),
        Item(ADDR_GOAL_VELOCITY, 4, 0, signed=True),
        Item(108, 4, 0),  # Profile Acceleration
        Item(112, 4, 0),  # Profile Velocity
        Item(ADDR_GOAL_POSITION, 4, 0, signed=True),
        Item(ADDR_REALTIME_TICK, 2, 0, writable=False),
        Item(ADDR_MOVING, 1, 0, writable=False),
        Item(123, 1, 0, writable=False),  # Moving Status
        Item(124, 2, 0, writable=False, signed=True),  # Present PWM
        Item(ADDR_PRESENT_LOAD, 2, 0, writable=False, signed=True),
        Item(ADDR_PRESENT_VELOCITY, 4, 0, writable=False, signed=True),
        Item(ADDR_PRESENT_POSITION, 4, 0, writable=False, signed=True),
        Item(136, 4, 0, writable=False, signed=True),  # Velocity Trajectory
        Item(140, 4, 0, writable=False, signed=True),  # Position Trajectory
        Item(ADDR_PRESENT_VOLTAGE, 2, 120, writable=False),  # 0.1 V
        Item(ADDR_PRESENT_TEMPERATURE, 1, 35, writable=False),  # °C
    )
}
# Byte address -> item it belongs to, for detecting writes that cut an item or touch undefined
# addresses.
OWNER = {a: item for item in ITEMS.values() for a in range(item.address, item.address + item.size)}
GOALS = (
    ADDR_GOAL_PWM,
    ADDR_GOAL_VELOCITY,
    ADDR_GOAL_POSITION,  # read-only while a bus-watchdog error is latched
)
COMPUTED = (ADDR_REALTIME_TICK, ADDR_MOVING, ADDR_PRESENT_VELOCITY, ADDR_PRESENT_POSITION)

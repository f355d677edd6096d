"""Parameters of the dynamixel_driver: the one list of declarations (SPECS).

Names, units and ranges: docs/nodes/hsa_dynamixel_driver.md. Only ``max_goal_rate``,
``command_timeout`` and ``watchdog_action`` change at run time; every other parameter is read-only.
"""

from __future__ import annotations

import math
from typing import Any

from rclpy.parameter import Parameter

from hsa_common.model_params import WIRING_SPEC
from hsa_common.parameters import ParamSpec
from hsa_core.model.actuation import DEFAULT_MAX_GOAL_RATE
from hsa_dynamixel_driver.bus import SDK_BAUDRATES


def _neutral_ticks(value: Any) -> str | None:
    """Validator: unset/empty (the wiring's nominal), or 4 tick counts within ±1e6."""
    if value is None or len(value) == 0:
        return None
    if len(value) != 4 or not all(isinstance(v, int) and abs(v) <= 1_000_000 for v in value):
        return f"must be empty or 4 tick counts within ±1e6, got {list(value)!r}"
    return None


SPECS = (
    ParamSpec(
        "autostart",
        True,
        "configure and activate at start (no lifecycle manager needed)",
        read_only=True,
    ),
    ParamSpec(
        "port",
        "/dev/ttyUSB0",
        "serial device of the U2D2 (a stable udev symlink is best)",
        read_only=True,
    ),
    ParamSpec(
        "baudrate",
        4_000_000,
        "bus speed [bit/s]; must equal the servos' Baud Rate register",
        read_only=True,
        validator=lambda v: None if v in SDK_BAUDRATES else f"must be one of {SDK_BAUDRATES}",
    ),
    WIRING_SPEC,
    ParamSpec(
        "material",
        "fpu",
        "parameter set giving the rods' handedness h and twist limit phi_max",
        choices=("fpu", "epu"),
        read_only=True,
    ),
    ParamSpec(
        "params_file",
        "",
        "parameter YAML overriding the packaged set (empty = packaged)",
        read_only=True,
    ),
    ParamSpec(
        "goal_margin",
        0.02,
        "goal clamp widening beyond [0, phi_max] on both ends [rad]",
        low=0.0,
        high=0.5,
        read_only=True,
    ),
    ParamSpec(
        "neutral_source",
        "param",
        "neutral ticks (and so the absolute goal limits): the neutral_ticks list, "
        "neutral_file, or read (the φ map only, accepted within neutral_tolerance of "
        "neutral_ticks; the limits "
        "stay on neutral_ticks)",
        choices=("param", "file", "read"),
        read_only=True,
    ),
    ParamSpec(
        "neutral_ticks",
        Parameter.Type.INTEGER_ARRAY,
        "configured neutral positions [ticks] (neutral_source 'param' or 'read'); unset = the "
        "wiring file's nominal neutral_ticks (the emulated servos' power-on position)",
        read_only=True,
        validator=_neutral_ticks,
    ),
    ParamSpec(
        "neutral_file",
        "",
        "YAML of stored neutral ticks; written from the present positions if absent",
        read_only=True,
    ),
    ParamSpec(
        "neutral_tolerance",
        0.1,
        "largest |present - stored neutral| at start-up for torque-on [rad]",
        low=0.0,
        high=math.pi,
        read_only=True,
    ),
    ParamSpec(
        "return_delay",
        0,
        "Return Delay Time written at configure [2 us units]",
        low=0,
        high=254,
        read_only=True,
    ),
    ParamSpec(
        "rate",
        100.0,
        "control cycle rate: one sync write + one sync read [Hz]",
        low=1.0,
        high=500.0,
        read_only=True,
    ),
    ParamSpec(
        "max_goal_rate",
        DEFAULT_MAX_GOAL_RATE,
        "largest goal speed of a motor [rad/s] (default: twice the "
        "MX-28 no-load speed); 0 = no rate limit",
        low=0.0,
        high=100.0,
    ),
    ParamSpec(
        "write_on_command",
        True,
        "sync-write a goal as soon as a phi_cmd arrives (else only in the cycle); "
        "the read cycle, watchdog and rate limit are unchanged",
        read_only=True,
    ),
    ParamSpec(
        "command_timeout",
        0.1,
        "command watchdog: phi_cmd older than this [s] -> watchdog_action; 0 = off",
        low=0.0,
        high=10.0,
    ),
    ParamSpec(
        "watchdog_action",
        "hold",
        "when the watchdog expires: hold the last goal, or relax (torque off until "
        "the next phi_cmd, which re-enables torque if safe)",
        choices=("hold", "relax"),
    ),
    ParamSpec(
        "reconnect_period",
        1.0,
        "retry period while the bus is down [s]",
        low=0.05,
        high=60.0,
        read_only=True,
    ),
    ParamSpec(
        "torque_retry_period",
        0.25,
        "first delay before a torque-on that failed on the bus is tried again [s]; "
        "it doubles with each failure in a row up to torque_retry_max",
        low=0.01,
        high=60.0,
        read_only=True,
    ),
    ParamSpec(
        "torque_retry_max",
        5.0,
        "largest delay between torque-on retries [s] (at least torque_retry_period)",
        low=0.01,
        high=600.0,
        read_only=True,
    ),
    ParamSpec(
        "packet_timeout",
        0.0,
        "[ms] least time to wait for a status packet; 0 = the SDK's (about 34 ms). "
        "The simulated graph raises it: there a late reply is the machine's load, not the servo",
        low=0.0,
        high=10_000.0,
        read_only=True,
    ),
    ParamSpec(
        "error_limit",
        10,
        "consecutive failed cycles before the bus counts as lost",
        low=1,
        high=10_000,
        read_only=True,
    ),
)

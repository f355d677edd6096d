"""sim_node's diagnostics and exit report, built from snapshots of the world and the emulated bus
(no node needed).

Statuses and values: docs/nodes/hsa_sim_node.md, "Diagnostics" and "Exit".
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from hsa_common.diagnostics import ERROR, OK, WARN, Report
from hsa_core.sim.world import World
from hsa_sim_node.mx28_emulator import (
    ADDR_TORQUE_ENABLE,
    EmulatorStats,
    MX28Emulator,
    RegisterWrite,
)

MIN_REAL_TIME_FACTOR = 0.95
"""Wall clock: below this real-time factor the world falls behind the node clock (WARN)."""


def world_report(
    world: World,
    stats: Mapping[str, Any],
    rtf: float,
    lockstep: bool,
    disturbance: str,
    failure: str,
) -> Report:
    """``sim_node: world``: ERROR after a barrier failure or a diverged plant, WARN slower than real
    time (wall)."""
    values = {
        "clock": "lockstep" if lockstep else "wall",
        "real_time_factor": round(rtf, 3),
        "samples": stats["samples"],
        "instants": stats["instants"],
        "clock_resends": stats["resends"],
        "sim_time": round(stats["sim_time_ns"] * 1e-9, 3),
        "phi": np.round(world.twists(), 4).tolist(),
        "chiee": np.round(world.true_pose(), 5).tolist(),
        "payload": float(world.plant.m_pl),
        "disturbance": disturbance,
    }
    if failure:
        return Report(ERROR, failure, values)
    if not np.all(np.isfinite(world.x)):
        return Report(ERROR, "plant diverged", values)
    if not lockstep and rtf < MIN_REAL_TIME_FACTOR:
        return Report(WARN, f"slower than real time (factor {rtf:.2f})", values)
    return Report(OK, "running", values)


def emulator_report(
    emulator: MX28Emulator, ids: Sequence[int], stats: EmulatorStats, rates: Mapping[str, float]
) -> Report:
    """``sim_node: emulator``: ERROR unplugged, WARN while a servo is silent or reports a hardware
    error or after CRC errors; ``rates``: sync_writes and sync_reads per second over the reporting
    period."""
    silent, hw_errors = emulator.unresponsive(), emulator.hardware_errors()
    values = {
        "port": emulator.port,
        "device": emulator.device,
        **vars(stats),
        "sync_writes_per_s": round(rates["sync_writes"], 1),
        "sync_reads_per_s": round(rates["sync_reads"], 1),
        "unresponsive_ids": list(silent),
        **{f"torque_{i}": emulator.torque_enabled(i) for i in ids},
        **{f"hardware_error_{i}": bits for i, bits in hw_errors.items()},
    }
    if not emulator.plugged:
        return Report(ERROR, "unplugged", values)
    if silent or any(hw_errors.values()):
        return Report(
            WARN,
            f"faults: unresponsive {list(silent)}, hardware errors "
            f"{ {i: b for i, b in hw_errors.items() if b} }",
            values,
        )
    return Report(OK if stats.crc_errors == 0 else WARN, "serving", values)


def torque_at_exit(
    ids: Sequence[int], torque_on: Iterable[int], writes: Iterable[RegisterWrite]
) -> str:
    """Which servos still have torque on; else since when every servo is off (CLOCK_MONOTONIC of the
    first torque-off write after each servo's last torque-on write, latest over the servos)."""
    on = list(torque_on)
    if on:
        return f"emulated bus removed with torque on for IDs {on}"
    off_since: dict[int, float] = {}
    for write in writes:
        if write.address != ADDR_TORQUE_ENABLE:
            continue
        if write.value == 1:
            off_since.pop(write.dxl_id, None)
        else:
            off_since.setdefault(write.dxl_id, write.time)
    if len(off_since) < len(ids):
        return (
            "emulated bus removed with torque off on every servo (not every torque-off write is "
            "logged)"
        )
    return (
        f"emulated bus removed with torque off on every servo (off since monotonic "
        f"{max(off_since.values()):.6f} s)"
    )

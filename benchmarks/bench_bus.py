"""Benchmark of one control-cycle bus exchange: Sync Write of 4 goals + Sync Read of 4 present
positions.

Writes benchmarks/results/bus.json. The 4 servos are the pseudo-terminal MX-28(2.0) emulator in this
process (Return Delay Time 0 after configure, 4 Mbps line setting, which a pty ignores), so the
figures measure software overhead: SDK, driver, pty and emulator, not wire time (≈ 0.5 ms at 4 Mbps,
ecosystem.md §3.1). Two clients are timed on the same bus: ``driver`` (DynamixelBus, which waits in
select()) and ``sdk_busy_poll`` (the stock SDK PortHandler and
GroupSyncWrite/GroupSyncRead.txRxPacket, which spins). Figures are per-cycle wall-time median and
p99 in ms, plus CPU time of the whole process (emulator thread included) per cycle; the 1-minute
load average is recorded because other processes on the 2-core machine inflate them. Reference:
toolchain.md §7 measured the stock SDK at median 0.15 ms, p99 3.2 ms. Usage: .venv/bin/python
benchmarks/bench_bus.py [--cycles N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

from hsa_dynamixel_driver.bus import ADDR_GOAL_POSITION, ADDR_PRESENT_POSITION, DynamixelBus
from hsa_sim_node.mx28_emulator import MX28Emulator

RESULTS = Path(__file__).resolve().parent / "results" / "bus.json"
IDS = (21, 22, 23, 24)
BAUD = 4_000_000
WARMUP = 100
ROUNDS = 5
REFERENCE_MS = {"toolchain_sdk_median": 0.15, "toolchain_sdk_p99": 3.2}


def time_cycles(cycle: Callable[[int], None], n: int) -> dict[str, float]:
    """Median/p99/max wall time (ms) of n calls cycle(k) after WARMUP untimed ones, the lowest
    median of ROUNDS consecutive chunks, and process CPU ms (all threads, emulator included) per
    call."""
    for k in range(WARMUP):
        cycle(k)
    durations = np.empty(n, dtype=np.int64)
    cpu_start = time.process_time()
    for k in range(n):
        start = time.perf_counter_ns()
        cycle(k)
        durations[k] = time.perf_counter_ns() - start
    cpu_ms = (time.process_time() - cpu_start) * 1e3 / n
    return {
        "median_ms": round(float(np.median(durations)) / 1e6, 4),
        "p99_ms": round(float(np.percentile(durations, 99)) / 1e6, 4),
        "max_ms": round(float(durations.max()) / 1e6, 4),
        "best_round_median_ms": round(
            min(float(np.median(r)) for r in np.array_split(durations, ROUNDS)) / 1e6, 4
        ),
        "cpu_ms_per_cycle": round(cpu_ms, 4),
        "n": n,
    }


def goals(k: int) -> dict[int, int]:
    """A slowly changing, multi-turn set of goals."""
    return {dxl_id: 2048 + (k % 200) * 10 - i * 4096 for i, dxl_id in enumerate(IDS)}


def bench_driver(port: str, n: int) -> dict[str, float]:
    with DynamixelBus(port, BAUD, IDS) as bus:
        bus.configure(return_delay=0, torque_on=True)

        def cycle(k: int) -> None:
            bus.write_goals(goals(k))
            bus.read_positions()

        return time_cycles(cycle, n)


def bench_sdk(port_name: str, n: int) -> dict[str, float]:
    port, ph = PortHandler(port_name), PacketHandler(2.0)
    assert port.setBaudRate(BAUD)
    reader = GroupSyncRead(port, ph, ADDR_PRESENT_POSITION, 4)
    for dxl_id in IDS:
        reader.addParam(dxl_id)

    def cycle(k: int) -> None:
        writer = GroupSyncWrite(port, ph, ADDR_GOAL_POSITION, 4)
        for dxl_id, ticks in goals(k).items():
            writer.addParam(dxl_id, list(ticks.to_bytes(4, "little", signed=True)))
        if writer.txPacket() != COMM_SUCCESS or reader.txRxPacket() != COMM_SUCCESS:
            raise RuntimeError("sync write/read failed")

    try:
        return time_cycles(cycle, n)
    finally:
        port.closePort()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=3000)
    args = parser.parse_args()
    load_start = os.getloadavg()[0]
    with MX28Emulator(IDS, baudrate=BAUD) as emulator:
        results = {
            "driver": bench_driver(emulator.port, args.cycles),
            "sdk_busy_poll": bench_sdk(emulator.port, args.cycles),
        }
        stats = emulator.stats()
    report = {
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "loadavg_1min_at_start": round(load_start, 2),
            "loadavg_1min_at_end": round(os.getloadavg()[0], 2),
        },
        "setup": {
            "servos": len(IDS),
            "baudrate": BAUD,
            "return_delay_2us": 0,
            "emulator": "same process, pty",
        },
        "reference_ms": REFERENCE_MS,
        "cycle_sync_write_plus_sync_read": results,
        "emulator_counters": {"crc_errors": stats.crc_errors, "sync_writes": stats.sync_writes},
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report["cycle_sync_write_plus_sync_read"], indent=2))


if __name__ == "__main__":
    main()

"""Fixtures of the driver tests: the emulated bus and the driver processes started on it (import
them into a test module and name them in its ``__all__``)."""

from __future__ import annotations

import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from hsa_sim_node.mx28_emulator import MX28Emulator
from tests.ros.conftest import start_process, stop_process, wait_for_line
from tests.ros.driver_harness import DriverProcess, driver_args, make_emulator


@pytest.fixture
def emulator(tmp_path: Path) -> Iterator[MX28Emulator]:
    """The emulated bus with the test neutrals and fast servos, stopped at teardown."""
    emu = make_emulator(tmp_path)
    try:
        yield emu
    finally:
        emu.stop()


@pytest.fixture
def drivers() -> Iterator[list[DriverProcess]]:
    """A list the test appends its DriverProcess objects to; those still running are stopped at
    teardown."""
    procs: list[DriverProcess] = []
    yield procs
    for proc in procs:
        if proc.proc.poll() is None:
            proc.stop()


@pytest.fixture
def driver(emulator: MX28Emulator) -> Iterator[Callable[..., subprocess.Popen]]:
    """``driver(*overrides, ready=True)`` starts the driver on the emulated bus (and waits until it
    is ready); every one is stopped at teardown."""
    procs: list[subprocess.Popen] = []

    def _start(*overrides: str, ready: bool = True) -> subprocess.Popen:
        proc = start_process(driver_args(emulator.port, overrides))
        procs.append(proc)
        if ready:
            wait_for_line(proc, "ready", timeout=60.0)
        return proc

    yield _start
    for proc in procs:
        stop_process(proc)

"""Fixtures for hardware-layer tests: an emulated MX-28(2.0) bus on a pseudo-terminal and a driver
opened on it."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
from dynamixel_sdk import PacketHandler, PortHandler

from hsa_dynamixel_driver.bus import DynamixelBus
from hsa_sim_node.mx28_emulator import MX28Emulator, ServoModel

IDS = (21, 22, 23, 24)
BAUD = 4_000_000
# keeps motion tests short
FAST_SERVO = ServoModel(time_constant_s=0.01, max_speed_ticks_per_s=50_000.0)


@pytest.fixture
def baud() -> int:
    """Line speed of the emulated servos and of every client in these tests."""
    return BAUD


@pytest.fixture
def emulator(tmp_path) -> Iterator[MX28Emulator]:
    with MX28Emulator(IDS, baudrate=BAUD, model=FAST_SERVO, link_path=tmp_path / "ttyDXL") as emu:
        yield emu


@pytest.fixture
def bus(emulator: MX28Emulator) -> Iterator[DynamixelBus]:
    driver = DynamixelBus(emulator.port, BAUD, IDS)
    driver.open()
    yield driver
    driver.close()


@pytest.fixture
def sdk(emulator: MX28Emulator) -> Iterator[tuple[PortHandler, PacketHandler]]:
    """The bare SDK on the emulator, for protocol-level checks."""
    port = PortHandler(emulator.port)
    assert port.setBaudRate(BAUD)
    yield port, PacketHandler(2.0)
    port.closePort()


@pytest.fixture
def wait_for() -> Callable[..., bool]:
    """``wait_for(condition, timeout_s=2.0)``: poll until the condition holds or the time is up."""

    def poll(condition: Callable[[], bool], timeout_s: float = 2.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition():
                return True
            time.sleep(0.005)
        return condition()

    return poll

"""Test-side launcher of the real dynamixel_driver whose control cycle raises ``InjectedFault`` (an
uncaught exception) while a given file exists: test_shutdown_torque proves that the runner's
shutdown guard still turns torque off (exit code 1). It runs the production path —
``DynamixelDriver`` under ``hsa_common.runner.run`` after ``configure_jax``, as
``hsa_dynamixel_driver.node.main`` does — with only the cycle wrapped.

argv: the fault file, then the driver's ``--ros-args``.
"""

import sys
from pathlib import Path

from hsa_common.runner import run
from hsa_core.jaxsetup import configure_jax
from hsa_dynamixel_driver.node import DynamixelDriver


class InjectedFault(RuntimeError):
    """The uncaught exception raised in the driver's control cycle while the fault file exists."""


class FaultyDriver(DynamixelDriver):
    """DynamixelDriver whose control cycle raises InjectedFault while ``fault_file`` exists."""

    def __init__(self, fault_file: Path) -> None:
        """The production driver, with the hook armed on ``fault_file``."""
        super().__init__()
        self._fault_file = fault_file
        self.get_logger().warning(
            f"test hook armed: the control cycle raises while {fault_file} exists"
        )

    def _cycle(self) -> None:
        """Raise while the fault file exists, else the production cycle."""
        if self._fault_file.exists():
            raise InjectedFault(f"injected by {self._fault_file}")
        super()._cycle()


def main() -> None:
    """Run the faulty driver as the console entry point runs the real one."""
    fault_file = Path(sys.argv.pop(1))  # rclpy reads the rest of argv (--ros-args ...)
    configure_jax()
    raise SystemExit(run(lambda: FaultyDriver(fault_file), "dynamixel_driver"))


if __name__ == "__main__":
    main()

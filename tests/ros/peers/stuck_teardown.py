"""A node under ``hsa_common.runner.run`` whose ``destroy_node`` hangs in native code holding the
GIL, as rclpy's did inside the middleware beside busy processes: test_exit_deadline proves the
runner still ends the process, with the node's exit code.

argv: the exit code the node sets.
"""

import ctypes
import sys

from rclpy.node import Node

from hsa_common.runner import run


class StuckTeardown(Node):
    """A node without timers whose teardown never returns on its own."""

    def __init__(self, code: int) -> None:
        super().__init__("stuck_teardown")
        self.exit_code = code

    def destroy_node(self) -> None:
        """Block in a C call that keeps the GIL (a 60 s libc sleep through ctypes.PyDLL)."""
        ctypes.PyDLL(None).sleep(60)


if __name__ == "__main__":
    code = int(sys.argv[1])
    sys.exit(run(lambda: StuckTeardown(code), "stuck_teardown"))

"""A node under ``hsa_common.runner.run`` whose timer callback hangs in native code holding the GIL
(it locks a pthread mutex it already holds, through ctypes.PyDLL: a deadlock, as a node stuck in
the middleware has): no Python of its own runs, so it ignores SIGINT and SIGTERM.
test_exit_deadline proves that the launcher then says where it is stuck before SIGKILL.
"""

import ctypes
import sys

from rclpy.node import Node

from hsa_common.runner import run


class StuckSpin(Node):
    """A node whose first timer callback never returns on its own."""

    def __init__(self) -> None:
        super().__init__("stuck_spin")
        self.timer = self.create_timer(0.2, self.hang_in_native_code)

    def hang_in_native_code(self) -> None:
        """Say so, then deadlock in a C call that keeps the GIL (a signal does not end a futex
        wait)."""
        libc = ctypes.PyDLL(None)
        mutex = ctypes.create_string_buffer(64)  # zeroed: PTHREAD_MUTEX_INITIALIZER (glibc)
        libc.pthread_mutex_lock(mutex)
        print("stuck now", flush=True)
        libc.pthread_mutex_lock(mutex)


if __name__ == "__main__":
    sys.exit(run(StuckSpin, "stuck_spin"))

"""A node under ``hsa_common.runner.run`` whose construction takes 60 s (as a JAX compilation does,
only longer): test_exit_deadline proves a stop signal during construction ends the process at once.
"""

import sys
import time

from rclpy.node import Node

from hsa_common.runner import run


class SlowStart(Node):
    """A node that says when its construction has begun, then takes a minute to finish it."""

    def __init__(self) -> None:
        super().__init__("slow_start")
        print("constructing", flush=True)
        time.sleep(60)


if __name__ == "__main__":
    sys.exit(run(SlowStart, "slow_start"))

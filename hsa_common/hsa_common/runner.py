"""Entry-point runner shared by every hsa-ros node: environment guard, init, spin, and a shutdown that always runs.

``run(MyNode)`` returns the process exit code: 0 after SIGINT/SIGTERM, 2 when the parameters are refused at start
(the error names the parameter), 1 after an uncaught exception. In every case the node's ``on_shutdown()`` hook
runs before the process exits — the driver turns torque off there.
"""

from __future__ import annotations

from collections.abc import Callable

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from hsa_common.parameters import ParameterValidationError
from hsa_core import rosenv


def run(node_factory: Callable[[], Node], name: str, args: list[str] | None = None) -> int:
    """Create the node with ``node_factory`` and spin it until shutdown; see the module docstring for exit codes."""
    rosenv.ensure_for_node()
    rclpy.init(args=args)
    logger = rclpy.logging.get_logger(name)
    try:
        node = node_factory()
    except ParameterValidationError as exc:
        logger.fatal(f"refusing to start: {exc}")
        rclpy.try_shutdown()
        return 2
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        node.get_logger().info("ready")  # start-up (parameter checks, JAX compilation) is complete; tests wait for it
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass  # SIGINT/SIGTERM: rclpy shut the context down; an uncaught exception propagates after `finally`
    except (RCLError, RuntimeError):
        if rclpy.ok():
            raise
        # a signal shut the context down while a callback was publishing or a message was being taken (rclpy raises
        # RCLError or a pybind11 RuntimeError then): an orderly stop, not a failure
    finally:
        hook = getattr(node, "on_shutdown", None)
        if hook is not None:
            hook()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def seconds(duration: object) -> float:
    """rclpy Duration (e.g. the difference of two rclpy Times) → float seconds."""
    return duration.nanoseconds * 1e-9  # type: ignore[attr-defined]

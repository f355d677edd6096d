"""Session-wide test set-up: the project ROS environment is applied before rclpy is imported or
anything spawned."""

import os
import signal

from hsa_common import rosenv
from hsa_core.jaxsetup import configure_jax

# Tests run every generated message setter with its type/size checks (off by default in Jazzy for
# speed), so a node that fills a field wrongly fails here instead of on the robot. Child processes
# inherit it.
os.environ["ROS_PYTHON_CHECK_FIELDS"] = "1"
# The tests model a terminal session: a SIGHUP ignored by whoever started the run (nohup, a CI
# runner) would be inherited by every process they start and make each node behave as started with
# nohup (not tied to its parent, deaf to a closed terminal), so the session starts its processes
# with SIGHUP's default action.
if signal.getsignal(signal.SIGHUP) == signal.SIG_IGN:
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
# run-specific: a test session never takes the user's domain
ROS_DOMAIN_ID = rosenv.apply(rosenv.reserve_domain_id())
# the test process is an entry point like any other (hsa_core's import sets nothing)
configure_jax()


def pytest_collection_modifyitems(items: list) -> None:
    """Files with a test marked slow first, each group in its collected order: with two workers
    (pytest.ini, `--no-loadscope-reorder`) the longest files start early instead of one worker
    finishing the colcon build alone at the end."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow_files)

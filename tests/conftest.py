"""Session-wide test set-up: the project ROS environment is applied before rclpy is imported or anything spawned."""

import os

from hsa_common import rosenv
from hsa_core.jaxsetup import configure_jax

# Tests run every generated message setter with its type/size checks (off by default in Jazzy for speed), so a
# node that fills a field wrongly fails here instead of on the robot. Child processes inherit it.
os.environ["ROS_PYTHON_CHECK_FIELDS"] = "1"
ROS_DOMAIN_ID = rosenv.apply(rosenv.reserve_domain_id())  # run-specific: a test session never takes the user's domain
configure_jax()  # the test process is an entry point like any other (hsa_core's import sets nothing)

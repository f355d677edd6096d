"""QoS profiles of the hsa-ros topics (one definition, used by every node, the recorder and the
player).

* Streams (mocap, planar state, motor states): sensor-data profile, best effort, keep last 5. Late
  data is useless.
* Commands (actuation): reliable, keep last 1 — never a queue of stale goals (reference_ros_graph.md
  §6, weakness 3).
* Setpoints and the E-stop state: reliable and transient-local, keep last 1, so a late joiner gets
  the current one.
* Services (``plan_setpoint``, the server and every client): reliable, keep all. With rclpy's
  default (keep last 10) a burst of requests overwrites queued requests in the server's histories
  and answers in the client's own; with keep all none is overwritten, and a full reader history
  makes the client's send fail loudly instead. A client passes ``qos_profile=SERVICE`` to
  ``create_client`` (docs/nodes/hsa_planner_node.md, "Bursts and service QoS").
Every publisher and subscription is created with ``OVERRIDABLE`` so a lab can change
reliability/depth/durability by the standard
``qos_overrides.<topic>.<publisher|subscription>.<policy>`` parameters.
"""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rclpy.qos_overriding_options import QoSOverridingOptions

SENSOR: QoSProfile = qos_profile_sensor_data
COMMAND = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
LATCHED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
INFO = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

SERVICE = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)


def overridable() -> QoSOverridingOptions:
    """QoS overriding options for reliability, history, depth and durability via parameters."""
    return QoSOverridingOptions.with_default_policies()

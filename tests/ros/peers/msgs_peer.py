"""Peer process for test_msgs: publishes PlanarState at 50 Hz and serves PlanSetpoint with a
scripted answer."""

import sys

import rclpy
from rclpy.node import Node

from hsa_msgs.msg import PlanarState
from hsa_msgs.srv import PlanSetpoint


class Peer(Node):
    """Publishes a recognisable state and answers plan requests by echoing the target into the
    setpoint."""

    def __init__(self) -> None:
        super().__init__("msgs_peer")
        self.pub = self.create_publisher(PlanarState, "state", 10)
        self.count = 0
        self.create_timer(0.02, self.tick)
        self.create_service(PlanSetpoint, "plan", self.plan)

    def tick(self) -> None:
        msg = PlanarState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = "hsa_base"
        msg.chiee.x, msg.chiee.y, msg.chiee.theta = 0.001, 0.12, -0.05
        msg.q.kappa_be = float(self.count)
        msg.velocity_valid = True
        msg.window_samples = 20
        self.pub.publish(msg)
        self.count += 1

    def plan(
        self, request: PlanSetpoint.Request, response: PlanSetpoint.Response
    ) -> PlanSetpoint.Response:
        if request.y <= 0.0:
            response.success = False
            response.status = PlanSetpoint.Response.STATUS_UNREACHABLE
            response.message = f"y = {request.y} m is above the base"
            return response
        response.success = True
        response.status = PlanSetpoint.Response.STATUS_OK
        response.setpoint.chiee_des.x = request.x
        response.setpoint.chiee_des.y = request.y
        response.setpoint.phi_ss = [1.5, 2.5]
        response.planner_used = "static"
        return response


def main() -> None:
    rclpy.init()
    node = Peer()
    print("ready", flush=True)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    sys.exit(0)


if __name__ == "__main__":
    main()

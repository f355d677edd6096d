"""Peer process for test_plan_burst: sends N plan_setpoint requests back to back (asynchronously),
then spins until every future is done or a timeout passes, and prints one JSON line with the outcome
of each request."""

import json
import sys
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor

from hsa_common import qos
from hsa_msgs.srv import PlanSetpoint


def main() -> None:
    """argv: service name, number of requests, client QoS ('service' = hsa_common.qos.SERVICE,
    'default' = rclpy's), target y [m]."""
    service, n, profile, y = sys.argv[1], int(sys.argv[2]), sys.argv[3], float(sys.argv[4])
    rclpy.init()
    node = rclpy.create_node("plan_burst_peer")
    client = node.create_client(
        PlanSetpoint, service, **({"qos_profile": qos.SERVICE} if profile == "service" else {})
    )
    assert client.wait_for_service(timeout_sec=60.0), f"no service {service}"
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    # distinct reachable targets: answers are matched by x
    xs = [-0.004 + 0.008 * k / (n - 1) for k in range(n)]
    print("ready", flush=True)
    t0 = time.monotonic()
    futures = [client.call_async(PlanSetpoint.Request(x=x, y=y)) for x in xs]
    deadline = t0 + 60.0
    while time.monotonic() < deadline and not all(f.done() for f in futures):
        executor.spin_once(timeout_sec=0.05)
    elapsed = time.monotonic() - t0
    answers = [
        {
            "x": x,
            "done": f.done(),
            "success": f.done() and f.result().success,
            "answer_x": f.result().setpoint.chiee_des.x if f.done() else None,
            "status": f.result().status if f.done() else None,
            "message": f.result().message if f.done() else "",
        }
        for x, f in zip(xs, futures)
    ]
    print(json.dumps({"elapsed": elapsed, "answers": answers}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()

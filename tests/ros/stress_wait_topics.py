"""Stress check (not collected by pytest) of ``bag_player --wait-topics``: the subscriber must get
the first messages although its side of discovery lags the player's.

The subscriber's DDS threads run at the lowest CPU share (``idle``: SCHED_IDLE, ``nice``: nice 19)
beside BURNERS busy processes until its reader has matched the player's writer, then normally, so
only the start race can lose messages. Prints per trial how many leading messages were lost and how
many later ones. Run from the repository root with the project ROS environment, e.g.:

    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=89 .venv/bin/python \\
        -m tests.ros.stress_wait_topics TRIALS BURNERS idle|nice
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy

from hsa_common import rosenv
from hsa_common.launcher import find_executable
from hsa_msgs.msg import ControllerInfo
from tests.ros import test_bag_play

N_INFO = 80  # ControllerInfo messages in test_bag_play's bag


class _TmpFactory:
    """The one method of pytest's tmp_path_factory that the bag fixture uses."""

    def mktemp(self, name: str) -> Path:
        return Path(tempfile.mkdtemp(prefix=name))


def _starve_dds_threads(starve: bool, mode: str) -> None:
    """Lowest CPU share for this process's DDS threads (named dds.*), or back to normal."""
    for tid in os.listdir("/proc/self/task"):
        try:
            if not Path(f"/proc/self/task/{tid}/comm").read_text().startswith("dds."):
                continue
            if mode == "idle":
                policy = os.SCHED_IDLE if starve else os.SCHED_OTHER
                os.sched_setscheduler(int(tid), policy, os.sched_param(0))
            else:
                os.setpriority(os.PRIO_PROCESS, int(tid), 19 if starve else 0)
        except OSError:  # a thread that ended meanwhile
            pass


def main(trials: int, burners: int, mode: str) -> None:
    bag = test_bag_play.bag.__wrapped__(_TmpFactory())
    rclpy.init()
    node = rclpy.create_node("stress_probe")
    got: list[int] = []
    sub = node.create_subscription(
        ControllerInfo,
        test_bag_play.INFO,
        lambda m: got.append(m.setpoint.trajectory_index),
        QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE),
    )
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    threading.Thread(target=executor.spin, daemon=True).start()
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(burners)]
    results = []
    try:
        for trial in range(trials):
            got.clear()
            time.sleep(1.0)
            _starve_dds_threads(True, mode)
            state, info = test_bag_play.STATE, test_bag_play.INFO
            proc = subprocess.Popen(
                [
                    find_executable("hsa_bag", "bag_player"),
                    str(bag),
                    "--topics",
                    state,
                    info,
                    "--remap",
                    f"{state}:=/nobody",
                    "--wait-for-subscribers",
                    "60",
                    "--wait-topics",
                    info,
                ],
                env=rosenv.ros_environment(),
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
            while sub.get_publisher_count() == 0 and proc.poll() is None:
                time.sleep(0.001)
            _starve_dds_threads(False, mode)
            proc.communicate(timeout=120)
            time.sleep(0.5)
            first = next((i for i in range(N_INFO) if i in got), N_INFO)
            later = sorted(set(range(first, N_INFO)) - set(got))
            results.append((first, len(later)))
            print(f"trial {trial}: exit {proc.returncode}, first {first} lost, later lost {later}")
    finally:
        for proc in busy:
            proc.kill()
        executor.shutdown()
        rclpy.try_shutdown()
    print("(first lost, later lost) per trial:", results)


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3])

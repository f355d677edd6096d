"""Replay graph end to end, in lockstep: launch_scripts/replay.launch.yaml on a bag of a short sim
run regenerates every recorded ``state`` and ``controller_info``, identical, and the launcher exits
0 when the player is done.

Run 1: the sim graph (launch_scripts/sim.launch.yaml, three short FPU steps, P-satI-D,
clock:=lockstep) records a bag: the session's sim run (tests/ros/conftest.py sim_step_bag), the one
test_sim_in_the_loop checks against the offline experiment. Run 2: the replay graph
(clock:=lockstep, its default) plays that bag's mocap and setpoints into fresh mocap_bridge,
kinematics_node and controller_node processes and records the regenerated /hsa/* next to the
replayed originals (/replay/*) with record:=true. The player owns /clock: each message goes out at
the instant of its log time and the controller's 40 Hz timer runs at the instants it ran at in the
sim run, each after the graph took everything before it. So nothing is lost and nothing depends on
the machine's load: every state of the sim bag is replayed and regenerated bit-identical, within the
instant its mocap sample is played at, and every controller_info tick is regenerated with the same
stamps, setpoint, q^d and commands; only ``compute_time`` (the tick's wall-clock CPU time) differs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import deserialize_message

from hsa_bag.bagio import Bag
from hsa_msgs.msg import ControllerInfo, PlanarState
from tests.ros.conftest import (
    GRAPH_STOP,
    LAUNCHER,
    SIM_STEP_PERIOD,
    SIM_STEPS,
    start_process,
    stop_process,
)

pytestmark = [pytest.mark.ros, pytest.mark.slow]

LAUNCH = Path(__file__).parents[2] / "launch_scripts"
STEPS, STEP_PERIOD = SIM_STEPS, SIM_STEP_PERIOD  # setpoints, s each


def launch(graph: str, *args: str, timeout: float = 600.0) -> str:
    """Run a launch graph with hsa_common.launcher until it ends; return its output (asserting exit
    code 0)."""
    proc = start_process([*LAUNCHER, str(LAUNCH / graph), *GRAPH_STOP, *args])
    try:
        output, _ = proc.communicate(timeout=timeout)
    finally:
        stop_process(proc)
    assert proc.returncode == 0, output[-5000:]
    return output


Messages = dict[str, list[tuple[int, object]]]


@pytest.fixture(scope="module")
def runs(sim_step_bag: Path, tmp_path_factory) -> Messages:
    """Bag of a sim run, replayed through the replay graph: (log time, message) per topic of both
    bags."""
    work = tmp_path_factory.mktemp("replay")
    output = launch(
        "replay.launch.yaml",
        f"bag:={sim_step_bag}",
        "record:=true",
        f"bag_dir:={work / 'replay'}",
        "markers:=false",
    )
    assert "bag_player exited with 0" in output and "lockstep: simulated time starts" in output, (
        output[-5000:]
    )
    types = {"state": PlanarState, "controller_info": ControllerInfo}
    with Bag(sim_step_bag) as recorded:
        found: Messages = {
            "sim/mocap/platform/pose": [
                (t, deserialize_message(d, PoseStamped))
                for _, t, d in recorded.messages(["/mocap/platform/pose"])
            ]
        }
    for bag, prefix in ((sim_step_bag, "sim"), (work / "replay", "")):
        with Bag(bag) as recorded:
            for ns in ("/hsa", "/replay") if prefix == "" else ("/hsa",):
                for name, cls in types.items():
                    found[f"{prefix}{ns}/{name}"] = [
                        (t, deserialize_message(d, cls))
                        for _, t, d in recorded.messages([f"{ns}/{name}"])
                    ]
    return found


def stamp(msg: object) -> int:
    """Header stamp [ns]."""
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec  # type: ignore[attr-defined]


def state_vector(s: PlanarState) -> np.ndarray:
    """[χ_ee, q, χ̇_ee, q̇, valid, window] of a state."""
    return np.array(
        [
            s.chiee.x,
            s.chiee.y,
            s.chiee.theta,
            s.q.kappa_be,
            s.q.sigma_sh,
            s.q.sigma_ax,
            s.chiee_dot.x,
            s.chiee_dot.y,
            s.chiee_dot.theta,
            s.q_dot.kappa_be,
            s.q_dot.sigma_sh,
            s.q_dot.sigma_ax,
            float(s.velocity_valid),
            float(s.window_samples),
        ]
    )


def test_every_recorded_state_is_replayed_and_regenerated_identical(runs: Messages) -> None:
    original, replayed, again = runs["sim/hsa/state"], runs["/replay/state"], runs["/hsa/state"]
    # the sim run's states (200 Hz mocap)
    assert len(original) >= 100 * STEPS * STEP_PERIOD, len(original)
    # every one played, recorded at its log time
    assert [t for t, _ in replayed] == [t for t, _ in original]
    # every one regenerated, in order
    assert [stamp(m) for _, m in again] == [stamp(m) for _, m in original]
    for (_, recorded), (_, regenerated) in zip(
        original, again
    ):  # same samples, same order: bit-identical
        np.testing.assert_array_equal(state_vector(regenerated), state_vector(recorded))
    # each computed within the instant its mocap sample was played at (the sim bag may log a state
    # some instants after its sample: the simulator synchronises the graph less often than the
    # player)
    played_at = {stamp(m): t for t, m in runs["sim/mocap/platform/pose"]}
    assert [t for t, _ in again] == [played_at[stamp(m)] for _, m in again]


def test_every_controller_tick_is_regenerated_identical(runs: Messages) -> None:
    original, replayed = runs["sim/hsa/controller_info"], runs["/replay/controller_info"]
    again = runs["/hsa/controller_info"]
    tracking = [m for _, m in original if m.state == ControllerInfo.STATE_TRACKING]
    # the 40 Hz ticks of the sim run
    assert len(tracking) >= 35 * STEPS * STEP_PERIOD, len(tracking)
    # each tick logged at its own instant
    assert [t for t, _ in original] == [stamp(m) for _, m in original]
    assert [stamp(m) for _, m in replayed] == [stamp(m) for _, m in original]
    # every tick, at its time
    assert [(t, stamp(m)) for t, m in again] == [(stamp(m), stamp(m)) for _, m in original]
    for (_, recorded), (_, regenerated) in zip(original, again):
        assert regenerated.state == recorded.state and regenerated.controller == recorded.controller
        assert regenerated.state_stamp == recorded.state_stamp
        assert regenerated.setpoint == recorded.setpoint
        for field in ("phi_ss", "phi_des_unsat", "phi_des_sat", "e_int"):
            np.testing.assert_array_equal(
                getattr(regenerated, field), getattr(recorded, field), err_msg=field
            )
        # the tick's wall-clock CPU time: not simulated
        regenerated.compute_time = recorded.compute_time
        assert regenerated == recorded

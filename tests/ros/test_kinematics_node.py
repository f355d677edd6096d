"""kinematics_node as a real process: q from FK-built poses, q̇ of a ramp, rejected samples,
parameters, and the chain mocap → mocap_bridge → kinematics_node."""

from __future__ import annotations

import math
import subprocess
from collections.abc import Iterator, Sequence

import jax
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.time import Time

from hsa_common import qos
from hsa_core.model.kinematics import end_effector_jacobian, end_effector_pose
from hsa_core.model.params import HsaParams, load_params
from hsa_core.sensing import mocap
from hsa_msgs.msg import PlanarPoseStamped, PlanarState
from tests.ros.conftest import (
    ParameterClient,
    assert_refused_at_start,
    start_node,
    stop_process,
    wait_for_line,
)
from tests.ros.test_mocap_bridge import (
    delta,
    pose_msg,
    prime,
    stamp_ns,
    start_bridge,
    status,
    stream,
    wait_until,
)

pytestmark = pytest.mark.ros

PERIOD_NS = 5_000_000  # 200 Hz
SIGMA_A_EQ = [0.97, 1.01]  # calibrated rest strains given to the node in /hsa
COMMON = ("qos_overrides./hsa/ee_pose.subscription.depth:=100", "diagnostics_period:=0.2")
RECEIVE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
STATUS = "kinematics_node: estimator"
# q ramp [1/m, -, -] and its rate per second
Q0, RATE = np.array([-2.0, 0.02, 0.05]), np.array([8.0, -0.1, 0.2])


def _start(params: Sequence[str], remaps: Sequence[str] = ("__ns:=/hsa",)) -> subprocess.Popen:
    """A kinematics_node process (default: in namespace /hsa) with ``name:=value`` parameters."""
    return start_node("hsa_kinematics_node", "kinematics_node", params, remaps)


@pytest.fixture(scope="module")
def nodes() -> Iterator[None]:
    """Started together in /hsa: a kinematics_node (FPU, calibrated SIGMA_A_EQ) fed by the tests,
    and a mocap_bridge feeding it in the end-to-end test only."""
    procs = [
        _start([*COMMON, f"sigma_a_eq:={SIGMA_A_EQ}"]),
        start_bridge(
            [
                "diagnostics_period:=0.2",
                "qos_overrides./mocap/platform/pose.subscription.depth:=100",
            ]
        ),
    ]
    for proc in procs:
        wait_for_line(proc, "ready", timeout=120.0)
    yield
    assert [stop_process(proc) for proc in procs] == [0, 0]


@jax.jit
def _pose_and_velocity(params: HsaParams, q: jax.Array) -> tuple[jax.Array, jax.Array]:
    """EE poses χ_ee(q_k) and velocities J_ee(q_k) RATE for a batch of configurations (jitted: eager
    takes ~10 s)."""
    pose = jax.vmap(end_effector_pose, in_axes=(None, 0))(params, q)
    return pose, jax.vmap(end_effector_jacobian, in_axes=(None, 0))(params, q) @ RATE


def _ramp(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Known configurations q_k = Q0 + RATE t_k at 200 Hz, their EE poses and EE velocities (FPU,
    SIGMA_A_EQ)."""
    q = Q0 + np.arange(n)[:, None] * 0.005 * RATE
    chiee, chiee_dot = _pose_and_velocity(load_params("fpu", sigma_a_eq=SIGMA_A_EQ), q)
    return q, np.asarray(chiee), np.asarray(chiee_dot)


def _planar_msg(stamp: int, chiee: Sequence[float]) -> PlanarPoseStamped:
    """An ee_pose message as the bridge sends it."""
    msg = PlanarPoseStamped()
    msg.header.stamp = Time(nanoseconds=stamp).to_msg()
    msg.header.frame_id = "hsa_base"
    msg.pose.x, msg.pose.y, msg.pose.theta = (float(v) for v in chiee)
    return msg


def _setup(node: Node) -> tuple[list[PlanarState], list[DiagnosticArray]]:
    """state and /diagnostics collectors of the test node."""
    diagnostics: list[DiagnosticArray] = []
    node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 50)
    states: list[PlanarState] = []
    sub = node.create_subscription(PlanarState, "/hsa/state", states.append, RECEIVE)
    assert wait_until(lambda: sub.get_publisher_count() >= 1), "kinematics_node not matched"
    return states, diagnostics


def _pose_input(node: Node) -> object:
    """The test node's ee_pose publisher in /hsa, matched with the kinematics node."""
    pub = node.create_publisher(PlanarPoseStamped, "/hsa/ee_pose", qos.SENSOR)
    assert wait_until(lambda: pub.get_subscription_count() >= 1), "kinematics_node not matched"
    return pub


def _q(state: PlanarState) -> list[float]:
    """q of a state."""
    return [state.q.kappa_be, state.q.sigma_sh, state.q.sigma_ax]


def _q_dot(state: PlanarState) -> list[float]:
    """q̇ of a state."""
    return [state.q_dot.kappa_be, state.q_dot.sigma_sh, state.q_dot.sigma_ax]


def _primed(
    node: Node, chiee: np.ndarray
) -> tuple[list[PlanarState], list[DiagnosticArray], object, dict[str, str], list[int]]:
    """A test's state echo, diagnostics and ee_pose publisher, the node primed with chiee[0] (the
    diagnostics baseline after it), and one stamp per pose of chiee, a period apart from now."""
    states, diagnostics = _setup(node)
    pub = _pose_input(node)
    baseline = prime(
        node, pub, diagnostics, lambda t: _planar_msg(t, chiee[0]), echo=states, name=STATUS
    )
    states.clear()
    t0 = node.get_clock().now().nanoseconds
    return states, diagnostics, pub, baseline, [t0 + k * PERIOD_NS for k in range(len(chiee))]


def test_q_from_fk_poses_and_rates_of_a_ramp(nodes, ros_node) -> None:
    q, chiee, chiee_dot_known = _ramp(60)
    states, diagnostics, pub, baseline, stamps = _primed(ros_node, chiee)
    stream(pub, [_planar_msg(t, c) for t, c in zip(stamps, chiee)])

    assert wait_until(lambda: len(states) == 60, 10.0), f"{len(states)} of 60 states arrived"
    assert [stamp_ns(s) for s in states] == stamps
    for k, state in enumerate(
        states
    ):  # the priming samples were > gap_factor periods earlier: the window restarts
        assert state.header.frame_id == "hsa_base"
        assert [state.chiee.x, state.chiee.y, state.chiee.theta] == chiee[k].tolist()
        np.testing.assert_allclose(_q(state), q[k], rtol=0.0, atol=1e-9)
        assert state.window_samples == min(k + 1, 20) and state.velocity_valid == (k >= 19)
        if state.velocity_valid:
            np.testing.assert_allclose(_q_dot(state), RATE, rtol=0.0, atol=1e-6)
            chiee_dot = [state.chiee_dot.x, state.chiee_dot.y, state.chiee_dot.theta]
            np.testing.assert_allclose(chiee_dot, chiee_dot_known[k], rtol=0.0, atol=1e-6)
        else:
            assert all(math.isnan(v) for v in _q_dot(state)), (
                "rates of a not-ready estimate must be NaN"
            )

    report, values = status(
        diagnostics, lambda s, v: delta(v, baseline, "published") == 60, name=STATUS
    )
    assert delta(values, baseline, "received") == 60 and values["rejected"] == baseline["rejected"]
    assert (
        report.level == DiagnosticStatus.OK
        and values["mode"] == "regular"
        and values["window_samples"] == "20/20"
    )
    assert values["sigma_a_eq"] == str(SIGMA_A_EQ) and float(values["output_rate_hz"]) > 0.0


def test_rejected_samples_produce_no_state(nodes, ros_node) -> None:
    q, chiee, _ = _ramp(40)
    states, diagnostics, pub, baseline, slot = _primed(ros_node, chiee)
    good = [_planar_msg(t, c) for t, c in zip(slot, chiee)]
    bad = [
        # non-finite (its stamp is reused by the next good sample)
        _planar_msg(slot[25], [math.nan, 0.11, 0.0]),
        _planar_msg(slot[24], chiee[24] + 0.001),  # duplicate stamp
        _planar_msg(slot[24] - 1_000_000, chiee[24]),  # out of order
    ]
    stream(pub, [*good[:25], *bad, *good[25:]])

    assert wait_until(lambda: len(states) == 40, 10.0), f"{len(states)} of 40 states arrived"
    assert [stamp_ns(s) for s in states] == slot
    for k, state in enumerate(states):  # rejected samples neither appear nor break the window
        assert [state.chiee.x, state.chiee.y, state.chiee.theta] == chiee[k].tolist()
        assert state.velocity_valid == (k >= 19)
    _, values = status(diagnostics, lambda s, v: delta(v, baseline, "received") == 43, name=STATUS)
    # priming gap
    assert (
        delta(values, baseline, "rejected") == 3 and delta(values, baseline, "window_restarts") == 1
    )
    for reason in ("non-finite stamp or sample", "duplicate stamp", "out-of-order stamp"):
        assert (
            int(values[f"rejected: {reason}"]) - int(baseline.get(f"rejected: {reason}", 0)) == 1
        ), values


def test_refused_run_time_update_keeps_the_old_value(nodes, ros_node) -> None:
    params = ParameterClient(ros_node, "/hsa/kinematics_node")
    set_one, get = params.set, params.get

    for name, value in (
        ("gap_factor", 0.5),
        ("regular_tol", -1.0),
        ("material", "epu"),
        ("window", 30),
    ):
        result = set_one(name, value)
        assert not result.successful and name in result.reason, result.reason
    assert (get("gap_factor"), get("regular_tol"), get("material"), get("window")) == (
        5.0,
        1e-3,
        "fpu",
        20,
    )
    assert set_one("gap_factor", 2.5).successful and get("gap_factor") == 2.5
    assert set_one("gap_factor", 5.0).successful  # back to the default for the other tests


def test_chain_from_mocap_to_state(nodes, ros_node) -> None:
    states, diagnostics = _setup(ros_node)
    pub = ros_node.create_publisher(PoseStamped, "/mocap/platform/pose", qos.SENSOR)
    assert wait_until(lambda: pub.get_subscription_count() >= 1), "mocap_bridge not matched"
    q, chiee, _ = _ramp(60)
    world = [mocap.planar_to_world(c, (0.0, 0.0, 0.0)) for c in chiee]
    prime(ros_node, pub, diagnostics, lambda t: pose_msg(t, *world[0]), echo=states, name=STATUS)
    states.clear()

    t0 = ros_node.get_clock().now().nanoseconds
    stamps = [t0 + k * PERIOD_NS for k in range(60)]
    stream(pub, [pose_msg(t, *w) for t, w in zip(stamps, world)])

    assert wait_until(lambda: len(states) == 60, 10.0), f"{len(states)} of 60 states arrived"
    assert [stamp_ns(s) for s in states] == stamps
    for k, state in enumerate(states):
        np.testing.assert_allclose(_q(state), q[k], rtol=0.0, atol=1e-9)
        assert state.velocity_valid == (k >= 19)
        if state.velocity_valid:
            np.testing.assert_allclose(_q_dot(state), RATE, rtol=0.0, atol=1e-6)


def test_bad_start_parameters_exit_2_naming_the_parameter() -> None:
    bad = {
        "sigma_a_eq": "sigma_a_eq:=[1.0]",  # one value for two rods (validator)
        "window": "window:=4",  # too short for a cubic (order 3 needs window >= 5)
    }
    assert_refused_at_start({name: _start([param]) for name, param in bad.items()})

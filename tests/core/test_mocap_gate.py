"""Tests of hsa_core.mocap_gate: every rule of the bridge's check chain, and recovery from one bad stamp (issue 10)."""

import math

import numpy as np
import pytest

from hsa_core.mocap import MocapConfig, WorkspaceBox, planar_to_world
from hsa_core.mocap_gate import GateConfig, MocapGate, Sample

T0 = 1_700_000_000_000_000_000  # [ns] a realistic epoch stamp
PERIOD = 5_000_000  # [ns] 200 Hz
REST_WORLD = (0.0, 0.0035 + 0.110 + 0.007, 0.0)  # hand-built: base at the origin, robot straight (test_mocap.py)
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def sample(stamp_ns: int, position=REST_WORLD, quaternion=IDENTITY, frame_id: str = "world") -> Sample:
    """A platform sample."""
    return Sample(stamp_ns, frame_id, tuple(position), tuple(quaternion))


def at(chiee, stamp_ns: int) -> Sample:
    """The platform sample of a planar pose (base at the origin)."""
    position, quaternion = planar_to_world(chiee, (0.0, 0.0, 0.0))
    return sample(stamp_ns, position, quaternion)


def stream(gate: MocapGate, stamps, latency: int = 1_000_000) -> list:
    """Reasons of rest-pose samples with these stamps, each received ``latency`` after its stamp."""
    return [gate.check(sample(s), s + latency).reason for s in stamps]


@pytest.fixture
def gate() -> MocapGate:
    """A gate with the default bounds that has accepted one sample at T0."""
    g = MocapGate(GateConfig())
    assert g.check(sample(T0), T0 + 1_000_000).reason is None
    return g


def test_rest_pose_is_accepted_and_projected(gate):
    verdict = gate.check(sample(T0 + PERIOD), T0 + PERIOD + 1_000_000)
    assert verdict.reason is None
    np.testing.assert_allclose(verdict.chiee, [0.0, 0.110, 0.0], atol=1e-12)


@pytest.mark.parametrize("frame_id", ["", "map", "World", "hsa_base"])
def test_wrong_frame_is_rejected_not_relabelled(gate, frame_id):
    verdict = gate.check(sample(T0 + PERIOD, frame_id=frame_id), T0 + PERIOD)
    assert verdict.reason == "frame" and repr(frame_id) in verdict.text
    assert gate.last_stamp_ns == T0  # the reference did not move


def test_expected_frame_is_a_parameter():
    g = MocapGate(GateConfig(frame_id="mocap"))
    assert g.check(sample(T0, frame_id="world"), T0).reason == "frame"
    assert g.check(sample(T0, frame_id="mocap"), T0).reason is None


@pytest.mark.parametrize("position, quaternion", [((math.nan, 0.12, 0.0), IDENTITY),
                                                  (REST_WORLD, (math.inf, 0.0, 0.0, 1.0))])
def test_non_finite_values(gate, position, quaternion):
    assert gate.check(sample(T0 + PERIOD, position, quaternion), T0 + PERIOD).reason == "non_finite"


def test_non_unit_quaternion(gate):
    assert gate.check(sample(T0 + PERIOD, quaternion=(0.0, 0.0, 0.0, 1.02)), T0 + PERIOD).reason == "quaternion"
    assert gate.check(sample(T0 + PERIOD, quaternion=(0.0, 0.0, 0.0, 1.005)), T0 + PERIOD).reason is None


def test_stale_by_stamp_against_the_clock(gate):
    assert gate.check(sample(T0 + PERIOD), T0 + PERIOD + 501_000_000).reason == "stale"  # max_age 0.5 s
    assert gate.check(sample(T0 + PERIOD), T0 + PERIOD + 499_000_000).reason is None
    assert MocapGate(GateConfig(max_age=0.0)).check(sample(T0), T0 + 10**10).reason is None  # 0 disables


def test_future_bound_is_small_and_independent_of_max_age(gate):
    # +0.4 s lies inside max_age (0.5 s) but far beyond max_future (0.01 s): the stamp cannot be a measurement
    verdict = gate.check(sample(T0 + 400_000_000), T0 + PERIOD)
    assert verdict.reason == "future" and gate.last_stamp_ns == T0
    assert gate.check(sample(T0 + PERIOD + 11_000_000), T0 + PERIOD).reason == "future"
    assert gate.check(sample(T0 + PERIOD + 9_000_000), T0 + PERIOD).reason is None


def test_future_stamp_followed_by_the_genuine_stream():
    """The issue-10 incident: one pose stamped +0.4 s, then the genuine 200 Hz stream (81 samples)."""
    g = MocapGate(GateConfig())
    genuine = [T0 + k * PERIOD for k in range(100)]
    assert stream(g, genuine[:10]) == [None] * 10
    assert g.check(sample(genuine[9] + 400_000_000), genuine[9] + 1_000_000).reason == "future"
    assert stream(g, genuine[10:91]) == [None] * 81  # every genuine sample accepted, from the first one


def test_future_stamp_inside_the_bound_holds_back_at_most_two_periods():
    g = MocapGate(GateConfig())
    assert stream(g, [T0]) == [None]
    bad = T0 + PERIOD + 9_000_000  # 9 ms ahead of the clock at arrival: accepted (inside max_future)
    assert g.check(sample(bad), T0 + PERIOD).reason is None
    reasons = stream(g, [T0 + k * PERIOD for k in range(1, 8)])
    assert reasons[:2] == ["out_of_order", "out_of_order"] and reasons[2:] == [None] * 5


def test_duplicate_and_out_of_order(gate):
    assert gate.check(sample(T0), T0 + PERIOD).reason == "duplicate"
    assert gate.check(sample(T0 - 1), T0 + PERIOD).reason == "out_of_order"
    assert gate.check(sample(T0 + 1), T0 + PERIOD).reason is None


def test_clock_that_went_back_is_followed_from_its_first_sample(gate):
    restart = T0 - 10 * 10**9  # a simulation or bag restarted 10 s earlier
    assert stream(gate, [restart, restart + PERIOD]) == [None, None]
    assert gate.time_resets == 1


def test_no_base_until_a_valid_base_pose():
    g = MocapGate(GateConfig(), MocapConfig(use_base_orientation=True))
    assert g.check(sample(T0), T0).reason == "no_base"
    assert g.base_sample(sample(T0, (0.0, 0.0, 0.0), IDENTITY, frame_id="map")) is not None  # wrong frame
    assert g.base_sample(sample(T0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 2.0))) is not None  # quaternion
    assert g.check(sample(T0), T0).reason == "no_base"
    assert g.base_sample(sample(T0, (0.0, 0.0, 0.0), IDENTITY)) is None
    verdict = g.check(sample(T0), T0)
    assert verdict.reason is None
    np.testing.assert_allclose(verdict.chiee, [0.0, 0.110, 0.0], atol=1e-12)


def test_workspace_box(gate):
    assert gate.check(at([0.0, 0.25, 0.0], T0 + PERIOD), T0 + PERIOD).reason == "workspace"
    narrow = MocapGate(GateConfig(workspace=WorkspaceBox(y=(0.12, 0.18))))
    assert narrow.check(sample(T0), T0).reason == "workspace"


def test_jump_scaled_by_the_time_since_the_last_accepted_sample(gate):
    # 4 m/s: 2 cm per 5 ms period
    assert gate.check(at([0.03, 0.110, 0.0], T0 + PERIOD), T0 + PERIOD).reason == "jump"
    assert gate.check(at([0.0, 0.110, 0.3], T0 + PERIOD), T0 + PERIOD).reason == "jump"  # 40 rad/s: 0.2 rad
    assert gate.check(at([0.015, 0.110, 0.0], T0 + PERIOD), T0 + PERIOD).reason is None
    assert gate.check(at([0.065, 0.110, 0.0], T0 + 3 * PERIOD), T0 + 3 * PERIOD).reason == "jump"  # 5 cm in 10 ms
    assert gate.check(at([0.065, 0.110, 0.0], T0 + 4 * PERIOD), T0 + 4 * PERIOD).reason is None  # in 15 ms


def test_rejected_samples_leave_the_references_unchanged(gate):
    for bad in (sample(T0 + PERIOD, frame_id=""), sample(T0 + 10**9), at([0.05, 0.110, 0.0], T0 + PERIOD),
                at([0.0, 0.25, 0.0], T0 + PERIOD)):
        assert gate.check(bad, T0 + PERIOD).reason is not None
    assert gate.last_stamp_ns == T0
    np.testing.assert_allclose(gate.last_chiee, [0.0, 0.110, 0.0], atol=1e-12)

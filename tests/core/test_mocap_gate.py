"""Tests of hsa_core.sensing.mocap_gate: every rule of the bridge's check chain, recovery from one
bad stamp (issue 10), the base stream's checks and timeout (issue 22) and the silence of a stream in
lockstep simulated time (issue 24)."""

import math

import numpy as np
import pytest

from hsa_core.sensing.mocap import MocapConfig, WorkspaceBox, planar_to_world
from hsa_core.sensing.mocap_gate import (
    REASONS,
    BaseMode,
    GateConfig,
    Health,
    MocapGate,
    Rejection,
    Sample,
)

T0 = 1_700_000_000_000_000_000  # [ns] a realistic epoch stamp
PERIOD = 5_000_000  # [ns] 200 Hz
REST_WORLD = (
    0.0,
    0.0035 + 0.110 + 0.007,
    0.0,  # hand-built: base at the origin, robot straight (test_mocap.py)
)
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def sample(
    stamp_ns: int, position=REST_WORLD, quaternion=IDENTITY, frame_id: str = "world"
) -> Sample:
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


@pytest.mark.parametrize(
    "position, quaternion",
    [((math.nan, 0.12, 0.0), IDENTITY), (REST_WORLD, (math.inf, 0.0, 0.0, 1.0))],
)
def test_non_finite_values(gate, position, quaternion):
    assert gate.check(sample(T0 + PERIOD, position, quaternion), T0 + PERIOD).reason == "non_finite"


def test_non_unit_quaternion(gate):
    assert (
        gate.check(sample(T0 + PERIOD, quaternion=(0.0, 0.0, 0.0, 1.02)), T0 + PERIOD).reason
        == "quaternion"
    )
    assert (
        gate.check(sample(T0 + PERIOD, quaternion=(0.0, 0.0, 0.0, 1.005)), T0 + PERIOD).reason
        is None
    )


def test_stale_by_stamp_against_the_clock(gate):
    # max_age 0.5 s
    assert gate.check(sample(T0 + PERIOD), T0 + PERIOD + 501_000_000).reason == "stale"
    assert gate.check(sample(T0 + PERIOD), T0 + PERIOD + 499_000_000).reason is None
    # 0 disables
    assert MocapGate(GateConfig(max_age=0.0)).check(sample(T0), T0 + 10**10).reason is None


def test_future_bound_is_small_and_independent_of_max_age(gate):
    # +0.4 s lies inside max_age (0.5 s) but far beyond max_future (0.01 s): the stamp cannot be a
    # measurement
    verdict = gate.check(sample(T0 + 400_000_000), T0 + PERIOD)
    assert verdict.reason == "future" and gate.last_stamp_ns == T0
    assert gate.check(sample(T0 + PERIOD + 11_000_000), T0 + PERIOD).reason == "future"
    assert gate.check(sample(T0 + PERIOD + 9_000_000), T0 + PERIOD).reason is None


def test_future_stamp_followed_by_the_genuine_stream():
    """The issue-10 incident: one pose stamped +0.4 s, then the genuine 200 Hz stream (81
    samples)."""
    g = MocapGate(GateConfig())
    genuine = [T0 + k * PERIOD for k in range(100)]
    assert stream(g, genuine[:10]) == [None] * 10
    assert g.check(sample(genuine[9] + 400_000_000), genuine[9] + 1_000_000).reason == "future"
    # every genuine sample accepted, from the first one
    assert stream(g, genuine[10:91]) == [None] * 81


def test_future_stamp_inside_the_bound_holds_back_at_most_two_periods():
    g = MocapGate(GateConfig())
    assert stream(g, [T0]) == [None]
    # 9 ms ahead of the clock at arrival: accepted (inside max_future)
    bad = T0 + PERIOD + 9_000_000
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
    assert g.base_mode(T0) is BaseMode.WAITING
    assert g.check(sample(T0), T0).reason == "no_base"
    assert (
        g.base_sample(sample(T0, (0.0, 0.0, 0.0), IDENTITY, frame_id="map"), T0).reason == "frame"
    )
    assert (
        g.base_sample(sample(T0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 2.0)), T0).reason == "quaternion"
    )
    assert g.check(sample(T0), T0).reason == "no_base"
    assert g.base_sample(sample(T0, (0.0, 0.0, 0.0), IDENTITY), T0).reason is None
    assert g.base_mode(T0) is BaseMode.LIVE
    verdict = g.check(sample(T0), T0)
    assert verdict.reason is None
    np.testing.assert_allclose(verdict.chiee, [0.0, 0.110, 0.0], atol=1e-12)


def based(base_timeout: float = 0.25) -> MocapGate:
    """A gate on a measured base that has accepted one base and one platform sample at T0."""
    g = MocapGate(GateConfig(base_timeout=base_timeout), MocapConfig(use_base_orientation=True))
    assert g.base_sample(sample(T0, (0.0, 0.0, 0.0)), T0 + 1_000_000).reason is None
    assert g.check(sample(T0), T0 + 1_000_000).reason is None
    return g


@pytest.mark.parametrize(
    "stamp, reason",
    [
        (5_000_000, "stale"),  # 1970, the incident of issue 22
        (T0 + PERIOD + 400_000_000, "future"),
        (T0 - PERIOD, "out_of_order"),
        (T0, "duplicate"),
    ],
)
def test_base_samples_get_the_stamp_checks_and_never_move_the_base(stamp, reason):
    g = based()
    now = T0 + PERIOD + 1_000_000
    shifted = (
        0.0,
        0.0,
        0.005,  # 5 mm in the plane: moved the EE estimate by 6.4 mm when accepted (issue 22)
    )
    assert [
        g.base_sample(sample(stamp + k, shifted), now).reason
        for k in range(10 if reason == "stale" else 1)
    ] == [reason] * (10 if reason == "stale" else 1)
    assert g.base == ((0.0, 0.0, 0.0), IDENTITY)
    verdict = g.check(sample(T0 + PERIOD), now)
    assert verdict.reason is None
    np.testing.assert_allclose(verdict.chiee, [0.0, 0.110, 0.0], atol=1e-12)


def test_a_stale_base_is_never_used_and_a_fresh_one_restores_the_stream():
    g = based(base_timeout=0.25)
    stamps = [T0 + k * PERIOD for k in range(1, 100)]  # 0.5 s of platform samples, no base sample
    reasons = [g.check(sample(s), s + 1_000_000).reason for s in stamps]
    cut = next(k for k, r in enumerate(reasons) if r is not None)
    assert (
        stamps[cut] + 1_000_000 - (T0 + 1_000_000)
    ) * 1e-9 > 0.25  # used up to its timeout, never beyond
    assert (stamps[cut - 1] + 1_000_000 - (T0 + 1_000_000)) * 1e-9 <= 0.25
    assert set(reasons[cut:]) == {"base_stale"}
    assert g.base_mode(stamps[-1] + 1_000_000) is BaseMode.STALE
    now = stamps[-1] + PERIOD
    # the base is back
    assert g.base_sample(sample(now - 1_000_000, (0.0, 0.0, 0.0)), now).reason is None
    assert g.base_mode(now) is BaseMode.LIVE
    assert g.check(sample(now), now + 1_000_000).reason is None


def test_a_base_pose_processed_late_is_judged_by_its_stamp():
    """A base sample that waited in a queue arrives fresh by the clock, but the platform sample it
    would be combined with is stamped more than base_timeout after it: that base is stale for it."""
    g = based(base_timeout=0.25)
    now = T0 + 400_000_000
    # 0.3 s in a queue
    assert g.base_sample(sample(T0 + 100_000_000, (0.0, 0.0, 0.0)), now).reason is None
    assert g.check(sample(T0 + 340_000_000), now).reason is None  # 0.24 s after the base's stamp
    verdict = g.check(sample(T0 + 360_000_000), now + 1_000_000)  # 0.26 s after it
    assert verdict.reason == "base_stale" and "0.26 s old" in verdict.text


def test_clock_going_back_drops_the_base_too():
    g = based()
    restart = T0 - 10 * 10**9
    # the old time line's base is not used
    assert g.check(sample(restart), restart).reason == "no_base"
    assert g.time_resets == 1 and g.base_mode(restart) is BaseMode.WAITING
    assert g.base_sample(sample(restart, (0.0, 0.0, 0.0)), restart).reason is None
    assert g.check(sample(restart + PERIOD), restart + PERIOD).reason is None


def test_platform_health_by_silence():
    g = MocapGate(GateConfig())
    assert g.health(T0) is Health.WAITING
    assert g.check(sample(T0), T0 + 1_000_000).reason is None
    assert g.health(T0 + 15_000_000) is Health.LIVE
    assert g.health(T0 + 17_000_000) is Health.GAP  # > 3 periods since it arrived
    assert g.health(T0 + 252_000_000) is Health.STALE


def test_lockstep_arrival_on_the_last_instant_is_no_gap():
    """Lockstep simulated time (issue 24; hsa_core.sim.sim_lockstep): /clock moves only at timer
    instants, every 25 ms; a sample becomes available 6 ms after its stamp and is processed with the
    clock of the newest instant (hence max_future 0.06 s in clock_lockstep.yaml). A report at an
    instant, before that instant's samples, reads LIVE."""
    g = MocapGate(GateConfig(max_future=0.06))
    instant, latency = 25_000_000, 6_000_000
    clock = 0
    for k in range(200):  # 1 s of simulated time
        available = k * PERIOD + latency
        while clock + instant < available:  # the instants before this sample: a report at each
            clock += instant
            assert g.health(T0 + clock) is Health.LIVE, (k, clock)
        assert g.check(sample(T0 + k * PERIOD), T0 + clock).reason is None


def test_workspace_box(gate):
    assert gate.check(at([0.0, 0.25, 0.0], T0 + PERIOD), T0 + PERIOD).reason == "workspace"
    narrow = MocapGate(GateConfig(workspace=WorkspaceBox(y=(0.12, 0.18))))
    assert narrow.check(sample(T0), T0).reason == "workspace"


def test_jump_scaled_by_the_time_since_the_last_accepted_sample(gate):
    # 4 m/s: 2 cm per 5 ms period
    assert gate.check(at([0.03, 0.110, 0.0], T0 + PERIOD), T0 + PERIOD).reason == "jump"
    # 40 rad/s: 0.2 rad
    assert gate.check(at([0.0, 0.110, 0.3], T0 + PERIOD), T0 + PERIOD).reason == "jump"
    assert gate.check(at([0.015, 0.110, 0.0], T0 + PERIOD), T0 + PERIOD).reason is None
    # 5 cm in 10 ms
    assert gate.check(at([0.065, 0.110, 0.0], T0 + 3 * PERIOD), T0 + 3 * PERIOD).reason == "jump"
    # in 15 ms
    assert gate.check(at([0.065, 0.110, 0.0], T0 + 4 * PERIOD), T0 + 4 * PERIOD).reason is None


def test_rejected_samples_leave_the_references_unchanged(gate):
    for bad in (
        sample(T0 + PERIOD, frame_id=""),
        sample(T0 + 10**9),
        at([0.05, 0.110, 0.0], T0 + PERIOD),
        at([0.0, 0.25, 0.0], T0 + PERIOD),
    ):
        assert gate.check(bad, T0 + PERIOD).reason is not None
    assert gate.last_stamp_ns == T0
    np.testing.assert_allclose(gate.last_chiee, [0.0, 0.110, 0.0], atol=1e-12)


def test_rejections_are_typed_reasons_in_check_order() -> None:
    """A verdict's reason is a Rejection member (the bridge counts it as is); REASONS lists them in
    check order under the names the bridge publishes (docs/nodes/hsa_mocap_bridge.md)."""
    gate = MocapGate(GateConfig())
    assert gate.check(sample(T0), T0).reason is None
    verdict = gate.check(sample(T0), T0 + PERIOD)
    assert type(verdict.reason) is Rejection and verdict.reason is Rejection.DUPLICATE
    assert [str(r) for r in REASONS] == [
        "frame",
        "non_finite",
        "quaternion",
        "stale",
        "future",
        "duplicate",
        "out_of_order",
        "no_base",
        "base_stale",
        "workspace",
        "jump",
    ]

"""Tests of hsa_core.sensing.estimation: Savitzky–Golay differentiation (spec §6.4) and the pose → q
helper (spec §6.3)."""

import math

import numpy as np
import pytest
from scipy.signal import savgol_coeffs, savgol_filter

from hsa_core.sensing.estimation import (
    EstimateMode,
    SampleRejection,
    SavitzkyGolayDifferentiator,
    derivative_coefficients,
)

T = 0.005  # 200 Hz mocap period

# spec §6.4, oldest to newest
SPEC_COEFFICIENTS = [
    -0.09166196123,
    -0.02180847375,
    0.0258122249,
    0.05407040425,
    0.06583633384,
    0.06398028319,
    0.05137252183,
    0.03088331928,
    0.005382945079,
    -0.02225833125,
    -0.04917024018,
    -0.07248251218,
    -0.08932487772,
    -0.09682706728,
    -0.09211881133,
    -0.07232984033,
    -0.03458988477,
    0.02397132489,
    0.1062240582,
    0.2150385846,
]


def feed(estimator, stamps, values):
    """Feed samples in order and return the list of estimates."""
    return [estimator.update(t, x) for t, x in zip(stamps, values)]


def cubic(t):
    """A cubic test signal (3 components) and its exact derivative."""
    # a0 + a1 t + ...
    coeffs = np.array([[0.3, -1.2, 4.0, -7.5], [-0.1, 0.4, 2.0, 3.0], [1.0, 0.0, -5.0, 20.0]])
    powers = np.asarray(t)[..., None] ** np.arange(4)
    d_powers = np.arange(4) * np.asarray(t)[..., None] ** np.maximum(np.arange(4) - 1, 0)
    return powers @ coeffs.T, d_powers @ coeffs.T


def test_precomputed_coefficients_match_spec():
    est = SavitzkyGolayDifferentiator()
    # 10 printed digits
    np.testing.assert_allclose(est.coefficients, SPEC_COEFFICIENTS, rtol=5.1e-10, atol=1e-13)
    tau = np.arange(20) - 19.0
    assert abs(est.coefficients.sum()) < 1e-12
    assert abs(est.coefficients @ tau - 1.0) < 1e-12


@pytest.mark.parametrize(("window", "order"), [(20, 3), (11, 2), (31, 4)])
def test_coefficients_match_scipy_endpoint(window, order):
    expected = savgol_coeffs(window, order, deriv=1, pos=window - 1, use="dot")
    np.testing.assert_allclose(
        derivative_coefficients(np.arange(window) - (window - 1.0), order), expected, atol=1e-12
    )


def test_regular_window_equals_scipy_savgol_at_last_sample():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(60, 6))
    stamps = 12.5 + T * np.arange(60)
    est = SavitzkyGolayDifferentiator(dim=6)
    for k, e in enumerate(feed(est, stamps, x)):
        if k < 19:
            continue
        expected = savgol_filter(x[k - 19 : k + 1], 20, 3, deriv=1, delta=T, axis=0, mode="interp")[
            -1
        ]
        assert e.mode == "regular" and e.ready
        np.testing.assert_allclose(e.derivative, expected, rtol=1e-9, atol=1e-9)


def test_noise_gain_and_frequency_response_match_spec():
    c = SavitzkyGolayDifferentiator().coefficients
    assert math.sqrt(np.sum(c**2)) / T == pytest.approx(70.0, rel=0.01)
    tau = np.arange(20) - 19.0
    for f, gain in [(1.0, 1.0006), (2.0, 1.009), (5.0, 1.25), (10.0, 2.2)]:
        w = 2.0 * math.pi * f
        response = abs(np.sum(c * np.exp(1j * w * tau * T))) / T
        assert response / w == pytest.approx(gain, abs=0.006 if gain < 2 else 0.05)


def test_start_up_reports_not_ready_never_zero():
    est = SavitzkyGolayDifferentiator(dim=3)
    x, _ = cubic(T * np.arange(25))
    for k in range(19):
        e = est.update(T * k, x[k])
        assert e.mode == "not_ready" and not e.ready and e.derivative is None
        np.testing.assert_array_equal(e.value, x[k])
        assert est.n_samples == k + 1
    for k in range(19, 25):
        e = est.update(T * k, x[k])
        assert e.ready and e.mode == "regular"
        assert est.n_samples == 20


def test_optional_startup_fit_is_flagged_and_exact_for_lines():
    est = SavitzkyGolayDifferentiator(dim=2, startup_order=1)
    stamps = 3.0 + T * np.arange(25)
    x = np.column_stack([2.0 - 0.5 * stamps, 0.1 * stamps])
    out = feed(est, stamps, x)
    assert [e.mode for e in out[:3]] == ["not_ready"] * 3  # fewer than order + 1 = 4 samples
    for e in out[3:19]:
        assert e.mode == "startup" and not e.ready
        np.testing.assert_allclose(e.derivative, [-0.5, 0.1], atol=1e-9)
    assert all(e.mode == "regular" and e.ready for e in out[19:])


def test_cubic_signal_differentiated_exactly_on_regular_and_irregular_stamps():
    rng = np.random.default_rng(2)
    regular = 0.2 + T * np.arange(40)
    jittered = 0.2 + np.cumsum(T * (1.0 + rng.uniform(-0.3, 0.3, 40)))
    for stamps, mode in [(regular, "regular"), (jittered, "irregular")]:
        x, dx = cubic(stamps)
        out = feed(SavitzkyGolayDifferentiator(), stamps, x)
        for k in range(19, 40):
            assert out[k].mode == mode
            np.testing.assert_allclose(out[k].derivative, dx[k], rtol=1e-8, atol=1e-8)


def test_irregular_fit_equals_least_squares_on_true_stamps():
    rng = np.random.default_rng(3)
    stamps = np.cumsum(T * (1.0 + rng.uniform(-0.4, 0.4, 30)))
    x = rng.normal(size=(30, 2))
    e = feed(SavitzkyGolayDifferentiator(dim=2), stamps, x)[-1]
    assert e.mode == "irregular"
    window_t, window_x = stamps[-20:], x[-20:]
    for j in range(2):
        poly = np.polynomial.Polynomial.fit(window_t - window_t[-1], window_x[:, j], 3)
        assert e.derivative[j] == pytest.approx(poly.deriv()(0.0), rel=1e-9, abs=1e-9)


def test_uniform_stamps_at_another_rate_use_true_times_and_agree_with_scipy():
    rng = np.random.default_rng(4)
    dt = 1.0 / 240.0  # uniform, but not the nominal 200 Hz
    x = rng.normal(size=(20, 1))
    e = feed(SavitzkyGolayDifferentiator(dim=1), dt * np.arange(20), x)[-1]
    assert e.mode == "irregular"
    expected = savgol_filter(x[:, 0], 20, 3, deriv=1, delta=dt, mode="interp")[-1]
    assert e.derivative[0] == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize(("offset", "mode"), [(0.45e-3, "regular"), (0.55e-3, "irregular")])
def test_jitter_rule_on_stamp_intervals(offset, mode):
    # alternating stamp offsets ±offset·T change every interval by 2·offset·T; the tolerance is
    # 1e-3·T
    stamps = T * np.arange(30) + offset * T * (-1.0) ** np.arange(30)
    x, _ = cubic(stamps)
    out = feed(SavitzkyGolayDifferentiator(), stamps, x)
    assert all(e.mode == mode for e in out[19:])


def test_gap_restarts_window():
    est = SavitzkyGolayDifferentiator(dim=1)
    stamps = list(T * np.arange(25))
    stamps += [stamps[-1] + 1.6 * T + T * k for k in range(20)]
    out = feed(est, stamps, np.ones((45, 1)))
    assert out[24].ready
    assert (
        out[25].mode == "not_ready" and "restarted" in out[25].reason and out[25].derivative is None
    )
    assert all(e.mode == "not_ready" for e in out[25:44])
    assert out[44].ready and out[44].mode == "regular"


def test_gap_below_limit_is_bridged_by_true_stamp_fit():
    est = SavitzkyGolayDifferentiator(dim=3)
    stamps = np.concatenate([T * np.arange(25), T * 24 + 1.4 * T + T * np.arange(10)])
    x, dx = cubic(stamps)
    out = feed(est, stamps, x)
    assert out[25].ready and out[25].mode == "irregular"
    np.testing.assert_allclose(out[25].derivative, dx[25], rtol=1e-8)


def test_rejections_leave_the_buffer_unchanged():
    stamps = T * np.arange(30)
    x, _ = cubic(stamps)
    est = SavitzkyGolayDifferentiator()
    feed(est, stamps[:20], x[:20])
    bad = [
        (stamps[19], x[19], "duplicate stamp"),
        (stamps[10], x[10], "out-of-order"),
        (stamps[19] + 0.5 * T, [np.nan, 0.0, 0.0], "non-finite"),
        (math.nan, x[0], "non-finite"),
        (math.inf, x[0], "non-finite"),
    ]
    for t, xi, reason in bad:
        e = est.update(t, xi)
        assert e.mode == "rejected" and not e.ready and e.value is None and e.derivative is None
        assert reason in e.reason
    last = feed(est, stamps[20:], x[20:])[-1]
    fresh = feed(SavitzkyGolayDifferentiator(), stamps, x)[-1]
    np.testing.assert_array_equal(last.derivative, fresh.derivative)


def test_rejections_carry_a_typed_reason():
    """The kinematics node counts rejections by this member (never by parsing the text)."""
    stamps = T * np.arange(20)
    x, _ = cubic(stamps)
    est = SavitzkyGolayDifferentiator()
    assert feed(est, stamps, x)[-1].mode is EstimateMode.REGULAR
    for t, xi, rejection in (
        (stamps[19], x[19], SampleRejection.DUPLICATE),
        (stamps[10], x[10], SampleRejection.OUT_OF_ORDER),
        (math.nan, x[0], SampleRejection.NON_FINITE),
    ):
        e = est.update(t, xi)
        assert e.mode is EstimateMode.REJECTED and e.rejection is rejection
        assert e.reason.startswith(str(rejection))
    older = est.update(stamps[10], x[10]).reason
    assert older == "out-of-order stamp (0.045 s older than the newest)"  # 9 periods of 5 ms


def test_value_is_a_private_copy_of_the_sample():
    est = SavitzkyGolayDifferentiator(dim=2)
    sample = np.array([1.0, 2.0])
    e = est.update(0.0, sample)
    sample[0] = 99.0
    np.testing.assert_array_equal(e.value, [1.0, 2.0])


def test_sine_velocity_within_the_documented_gain():
    stamps = T * np.arange(400)
    x = np.column_stack(
        [0.01 * np.sin(2 * np.pi * 1.0 * stamps), 0.01 * np.cos(2 * np.pi * 2.0 * stamps)]
    )
    out = feed(SavitzkyGolayDifferentiator(dim=2), stamps, x)
    true = np.column_stack(
        [
            0.02 * np.pi * np.cos(2 * np.pi * stamps),
            -0.04 * np.pi * np.sin(2 * np.pi * 2.0 * stamps),
        ]
    )
    err = np.array([e.derivative - v for e, v in zip(out[19:], true[19:])])
    # spec gains 1.0006 (1 Hz) and 1.009 (2 Hz); the causal end-point fit adds a phase lead of a few
    # mrad
    assert np.max(np.abs(err[:, 0])) < 3e-3 * 0.02 * np.pi
    assert np.max(np.abs(err[:, 1])) < 2e-2 * 0.04 * np.pi


def test_invalid_arguments():
    with pytest.raises(ValueError):
        SavitzkyGolayDifferentiator(window=4, order=3)
    with pytest.raises(ValueError):
        SavitzkyGolayDifferentiator(startup_order=3)
    with pytest.raises(ValueError):
        SavitzkyGolayDifferentiator(gap_factor=1.0)
    with pytest.raises(ValueError, match="shape"):
        SavitzkyGolayDifferentiator(dim=6).update(0.0, np.zeros(3))


def _forward_kinematics(xi, l=0.059, l_pc=0.025, l_dc=0.014, h_p=0.012):
    """EE pose of model.md §6.1–6.2 (closed form for κ ≠ 0, χ_off = 0), written out independently of
    hsa_core."""
    kappa, sigma_sh, sigma_ax = xi
    th = kappa * l
    p_x = (sigma_sh * math.sin(th) - sigma_ax * (1 - math.cos(th))) / kappa
    p_y = l_pc + (sigma_sh * (1 - math.cos(th)) + sigma_ax * math.sin(th)) / kappa
    d = l_dc + h_p  # distal platform surface, rotated by θ = κl
    return np.array([p_x - math.sin(th) * d, p_y + math.cos(th) * d, th])


@pytest.mark.parametrize("sigma_a_eq", [1.0, 1.02])
def test_configuration_from_pose_inverts_forward_kinematics(sigma_a_eq):
    from hsa_core.model.params import load_params
    from hsa_core.sensing.estimation import configuration_from_pose

    params = load_params("fpu").replace(sigma_a_eq=np.array([sigma_a_eq, sigma_a_eq]))
    for xi in ([-8.86, 0.0068, 1.298], [5.0, -0.05, 1.3], [0.3, 0.01, 1.1]):
        q = configuration_from_pose(params, _forward_kinematics(xi))
        assert isinstance(q, np.ndarray) and q.shape == (3,)
        np.testing.assert_allclose(q, np.array(xi) - [0.0, 0.0, sigma_a_eq], atol=1e-10)
    # straight robot at its undeformed height: ξ = [0, 0, 1]
    np.testing.assert_allclose(
        configuration_from_pose(params, [0.0, 0.110, 0.0]), [0, 0, 1 - sigma_a_eq], atol=1e-12
    )

"""Excitation sequences (identification.md §2.2, §2.4): timing, levels, GBN statistics, seeding,
zero-order hold."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from hsa_core.sysid import excitation

PHI_MAX = np.radians(200.0)


def runs(levels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lengths (samples) and values of the constant runs of a 1-D sequence."""
    change = np.flatnonzero(np.diff(levels) != 0.0) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(levels)]])
    return ends - starts, levels[starts]


def test_step_is_zero_then_the_level_on_the_rods_of_its_mode():
    exc = excitation.step(2.0, duration=3.0, t_step=1.0, mode="rod2", dt=0.04)
    assert len(exc.t) == 75 and exc.duration == pytest.approx(3.0)
    before, after = exc.t < 1.0, exc.t >= 1.0
    assert np.all(exc.phi[before] == 0.0)
    np.testing.assert_array_equal(exc.phi[after], np.tile([0.0, 2.0], (after.sum(), 1)))
    np.testing.assert_array_equal(excitation.step(2.0, 3.0, mode="elongation").phi[-1], [2.0, 2.0])
    np.testing.assert_array_equal(excitation.step(2.0, 3.0, mode="rod1").phi[-1], [2.0, 0.0])


def test_staircase_has_equal_increments_each_held_for_the_hold_time():
    exc = excitation.staircase(PHI_MAX, n_levels=5, hold=5.8, mode="elongation", dt=0.04)
    assert exc.duration == pytest.approx(6 * 5.8)
    lengths, values = runs(exc.phi[:, 0])
    np.testing.assert_allclose(values, PHI_MAX * np.arange(6) / 5, rtol=0, atol=1e-15)
    assert np.all(np.abs(lengths * 0.04 - 5.8) <= 0.04 + 1e-9)
    np.testing.assert_array_equal(exc.phi[:, 0], exc.phi[:, 1])


def test_gbn_levels_are_uniform_holds_average_the_settling_time_and_the_seed_fixes_the_draw():
    exc = excitation.gbn(
        PHI_MAX, duration=1200.0, seed=7, settling_time=0.5, mode="combined", dt=0.04
    )
    assert np.all((exc.phi >= 0.0) & (exc.phi <= PHI_MAX))
    for rod in range(2):
        lengths, values = runs(exc.phi[:, rod])
        # every switch draws a new level, so the run count equals the switch count: mean hold =
        # settling time
        assert np.mean(lengths[:-1]) * 0.04 == pytest.approx(0.5, rel=0.08)
        assert stats.kstest(values / PHI_MAX, "uniform").pvalue > 1e-3
        assert lengths.min() >= 1
    assert abs(np.corrcoef(exc.phi[:, 0], exc.phi[:, 1])[0, 1]) < 0.1  # combined: independent rods
    again = excitation.gbn(
        PHI_MAX, duration=1200.0, seed=7, settling_time=0.5, mode="combined", dt=0.04
    )
    other = excitation.gbn(
        PHI_MAX, duration=1200.0, seed=8, settling_time=0.5, mode="combined", dt=0.04
    )
    np.testing.assert_array_equal(exc.phi, again.phi)
    assert not np.array_equal(exc.phi, other.phi)
    assert exc.seed == 7 and exc.kind == "gbn"


def test_gbn_single_signal_modes():
    elong = excitation.gbn(PHI_MAX, 20.0, seed=1, mode="elongation")
    np.testing.assert_array_equal(elong.phi[:, 0], elong.phi[:, 1])
    bend = excitation.gbn(PHI_MAX, 20.0, seed=1, mode="rod1")
    assert np.all(bend.phi[:, 1] == 0.0) and np.ptp(bend.phi[:, 0]) > 0.0


def test_hold_lookup_and_resampling():
    exc = excitation.staircase(1.0, n_levels=2, hold=1.0, mode="rod1", dt=0.5)
    assert exc.at(-0.1).tolist() == [0.0, 0.0]
    assert exc.at(1.0).tolist() == [0.5, 0.0] and exc.at(1.49).tolist() == [0.5, 0.0]
    assert exc.at(100.0).tolist() == [1.0, 0.0]
    out = excitation.zero_order_hold(
        [0.0, 1.0, 2.0], [[0, 0], [1, 1], [2, 2]], [-1.0, 0.0, 0.99, 1.0, 5.0]
    )
    np.testing.assert_array_equal(out[:, 0], [0, 0, 0, 1, 2])


@pytest.mark.parametrize(
    "call",
    [
        lambda: excitation.step(-1.0, 3.0),
        lambda: excitation.staircase(1.0, n_levels=0),
        lambda: excitation.gbn(1.0, 10.0, seed=0, settling_time=0.01),
        lambda: excitation.gbn(1.0, 10.0, seed=0, mode="twist"),
        lambda: excitation.staircase(1.0, mode="combined"),
        lambda: excitation.make("sine", 1.0),
        lambda: excitation.step(1.0, 0.0),
    ],
)
def test_invalid_arguments_are_refused(call):
    with pytest.raises(ValueError):
        call()


def test_make_dispatches_by_kind():
    assert excitation.make("gbn", 1.0, duration=5.0, seed=3, mode="combined").seed == 3
    assert excitation.make("staircase", 1.0, n_levels=3, hold=1.0).duration == pytest.approx(4.0)
    assert excitation.make("step", 2.0, duration=2.0, level=1.5).phi[-1].tolist() == [1.5, 1.5]


def test_kind_and_mode_are_enum_members_whichever_way_they_were_named() -> None:
    """Callers may name the kind and mode (node parameters); the sequence carries the members."""
    exc = excitation.make("gbn", PHI_MAX, duration=1.0, mode="combined")
    assert exc.kind is excitation.ExcitationKind.GBN and exc.mode is excitation.RodMode.COMBINED
    kind, mode = excitation.ExcitationKind.STEP, excitation.RodMode.ROD1
    exc = excitation.make(kind, PHI_MAX, duration=2.0, mode=mode)
    assert exc.kind is excitation.ExcitationKind.STEP and exc.mode is excitation.RodMode.ROD1
    np.testing.assert_array_equal(exc.phi[-1], [PHI_MAX, 0.0])
    refusal = r"^kind must be one of \['step', 'staircase', 'gbn'\], got 'sine'$"
    with pytest.raises(ValueError, match=refusal):
        excitation.make("sine", PHI_MAX)

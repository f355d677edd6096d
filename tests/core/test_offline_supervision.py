"""The offline experiment runs controller_node's supervision: fault-free every tick with a setpoint
and a state tracks; with mocap samples withheld it holds, then stops, then tracks again as
docs/nodes/hsa_controller_node.md specifies.

Timeline by hand (defaults: 40 Hz ticks at k·25 ms, mocap stamped every 5 ms and available 6 ms
later, estimator window 20 samples, stale_timeout 0.1 s, hold_timeout 0.25 s): point 0 is planned at
100 ms, the estimator is ready with the sample stamped 95 ms (available at 101 ms), so the first
tick with a setpoint and a state is 125 ms (t = 0); the ticks at 25–100 ms wait for the setpoint.
Withholding the samples stamped in [2.0 s, 2.5 s): the newest state used is stamped 1.995 s, so
ticks up to 2.075 s (age 80 ms) track, 2.100–2.225 s (age 105–230 ms) hold the last command,
2.250–2.600 s send nothing; the window refills with the samples stamped 2.500–2.595 s (the last
available at 2.601 s), so tracking resumes at 2.625 s.
"""

from __future__ import annotations

import numpy as np
import pytest

from hsa_core.controller.supervision import Action, Mode
from hsa_core.sim.experiment import ExperimentConfig, run_experiment
from hsa_core.task.trajectories import TimedReference, step_reference

MS = 1_000_000


def _config(**kw) -> ExperimentConfig:
    """FPU P-satI-D on the first step point for 3 s."""
    ref = step_reference("fpu")
    return ExperimentConfig(
        "fpu", "psatid", reference=TimedReference(ref.t[:1], ref.p_des[:1], "one_step", 3.0), **kw
    )


@pytest.fixture(scope="module")
def runs():
    """The fault-free run and the one with the samples stamped in [2.0 s, 2.5 s) withheld."""
    return run_experiment(_config()), run_experiment(_config(mocap_outages=((2.0, 2.5),)))


def test_fault_free_every_tick_with_setpoint_and_state_tracks(runs) -> None:
    clean, _ = runs
    by_time = {r.t_ns: r for r in clean.ticks}
    assert [by_time[t * MS].mode for t in (25, 50, 75, 100)] == [Mode.WAITING_FOR_SETPOINT] * 4
    after = [r for r in clean.ticks if r.t_ns >= 125 * MS]
    assert len(after) == 120 and all(
        r.mode is Mode.TRACKING and r.sent is Action.STEP for r in after
    )
    assert len(clean.log) == 120


def test_withheld_states_hold_then_stop_then_track_again(runs) -> None:
    clean, faulty = runs
    by_time = {r.t_ns: r for r in faulty.ticks}
    hold = range(2100, 2250, 25)
    stop = range(2250, 2625, 25)
    assert all(by_time[t * MS].mode is Mode.TRACKING for t in range(125, 2100, 25))
    assert [by_time[t * MS].mode for t in hold] == [Mode.HOLD] * 6
    assert [by_time[t * MS].mode for t in stop] == [Mode.STALE] * 15
    assert all(by_time[t * MS].mode is Mode.TRACKING for t in range(2625, 3125, 25))
    last = by_time[2075 * MS]
    for t in hold:  # the last command re-sent unchanged, the law not stepped
        assert by_time[t * MS].sent is Action.HOLD and np.array_equal(by_time[t * MS].phi, last.phi)
    for t in stop:
        assert by_time[t * MS].sent is Action.NONE and np.all(np.isnan(by_time[t * MS].phi))
    for t in (*hold, *stop):  # integrators frozen through the hold and the stop
        assert np.array_equal(by_time[t * MS].e_int, last.e_int)
    assert len(faulty.log) == 120 - 6 - 15  # the log holds the tracking ticks
    n_before = (
        2000 - 125
    ) // 25 + 1  # up to 2.000 s the ticks use states stamped before the outage: unchanged
    np.testing.assert_array_equal(faulty.log.phi_sat[:n_before], clean.log.phi_sat[:n_before])
    np.testing.assert_array_equal(faulty.log.e_int[:n_before], clean.log.e_int[:n_before])

"""The batched JAX metrics (hsa_core.apps.batch_metrics) against their Python reference:
closed_loop.evaluate (hsa_core.analysis.metrics), robustness.classify and tune.effort, run by run on
the same logs, to 1e-9 relative."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from hsa_core.apps import batch_metrics, robustness, tune
from hsa_core.controller.control import ControllerKind
from hsa_core.model.actuation import MotorMap
from hsa_core.sim import closed_loop
from hsa_core.sim.experiment import ExperimentConfig
from hsa_core.task.trajectories import TimedReference, step_reference

RTOL = 1e-9


def short(material: str, seconds: float) -> TimedReference:
    """The material's step list cut to its first ``seconds`` (one step per 10 s), as
    test_closed_loop cuts it."""
    ref = step_reference(material)
    keep = ref.t < seconds
    return TimedReference(ref.t[keep], ref.p_des[keep], ref.name, seconds)


def reference(spec: closed_loop.LoopSpec, log: closed_loop.TickLog) -> dict[str, float]:
    """The Python path's figures of one run (NaN metrics where evaluate refuses non-finite
    positions)."""
    unstable, cycling = robustness.classify(spec, log)
    out = {"effort": tune.effort(log, spec), "unstable": unstable, "limit_cycle": cycling}
    try:
        m = closed_loop.evaluate(spec, log)
    except ValueError:
        return out | {"finite": False, "n_not_reached": -1} | {k: np.nan for k in FLOAT_FIELDS}
    return (
        out
        | {"finite": True, "n_ticks": m.n_ticks, "n_not_reached": m.n_not_reached}
        | {k: getattr(m, k) for k in FLOAT_FIELDS}
    )


FLOAT_FIELDS = (
    "rmse",
    "control_rate",
    "saturated_fraction",
    "response_time_mean",
    "settling_time_mean",
    "overshoot_mean",
    "overshoot_percent_mean",
    "steady_state_error_mean",
)


def assert_batch_matches(
    spec: closed_loop.LoopSpec, logs: list[closed_loop.TickLog]
) -> batch_metrics.RunSummary:
    """The batched summary of the stacked logs equals the reference of each log."""
    stacked = jax.tree_util.tree_map(lambda *leaves: np.stack(leaves), *logs)
    got = jax.tree_util.tree_map(np.asarray, batch_metrics.evaluate(spec, stacked))
    for i, log in enumerate(logs):
        one = jax.tree_util.tree_map(np.asarray, log)
        for key, want in reference(spec, one).items():
            value = getattr(got, key)[i]
            if isinstance(want, bool) or key.startswith("n_"):
                assert value == want, (i, key, value, want)
            else:
                np.testing.assert_allclose(
                    value, want, rtol=RTOL, atol=0.0, err_msg=f"run {i}, {key}"
                )
    return got


@pytest.mark.parametrize(
    "material, law, ee_integral, seconds, variants",
    [
        ("fpu", "psatid", False, 40.0, True),
        ("fpu", "pid", False, 40.0, False),
        ("fpu", "psatid_gc", True, 40.0, False),
        ("epu", "psatid", False, 20.0, False),
    ],
)
def test_closed_loop_runs_match_the_python_metrics(
    material: str, law: str, ee_integral: bool, seconds: float, variants: bool
) -> None:
    """Real runs: test_closed_loop's 40 s FPU runs (compiled once for both modules) and a 20 s EPU
    run; for P-satI-D also a perturbed plant with other noise, ten times the gains, and a run whose
    mocap turns NaN halfway."""
    config = ExperimentConfig(material, law, ee_integral, reference=short(material, seconds))
    spec, inputs, constants = closed_loop.prepare(config)
    runs = [inputs]
    if variants:
        plant = inputs.plant.replace(
            S_b_hat=np.asarray(inputs.plant.S_b_hat) * 1.08,
            C_eps=np.asarray(inputs.plant.C_eps) * 0.93,
        )
        broken = np.array(inputs.noise)
        broken[len(broken) // 2] = np.nan
        runs += [
            inputs._replace(
                plant=plant, noise=closed_loop.noise(config.base_world(), spec, seed=7)
            ),
            inputs._replace(gains=jax.tree_util.tree_map(lambda g: g * 10.0, inputs.gains)),
            inputs._replace(noise=broken),
        ]
    got = assert_batch_matches(spec, [closed_loop.compiled(spec, run, constants) for run in runs])
    assert np.all(got.finite[:3]) and not np.any(got.unstable[:3])
    if variants:
        assert not got.finite[3] and got.unstable[3] and np.isnan(got.rmse[3])


PERIOD_MS = 25
N_EVAL = 480  # 12 s at 40 Hz


def synthetic_spec() -> closed_loop.LoopSpec:
    return closed_loop.LoopSpec(
        ControllerKind.PSATID,
        False,
        None,
        PERIOD_MS,
        6,
        N_EVAL + 5,
        5,
        N_EVAL,
        MotorMap(phi_max=1.0),
        0.025,
    )


def synthetic_log(
    rng: np.random.Generator,
    first: int,
    setpoints: list[tuple[int, tuple[float, float]]],
    rows: int = N_EVAL + 5,
) -> closed_loop.TickLog:
    """A log whose law runs from row ``first``, setpoint (x, y) from each listed row on, the EE
    approaching each setpoint exponentially with noise; command a random walk with some saturated
    ticks."""
    desired = np.zeros((rows, 3))
    for row, xy in setpoints:
        desired[row:, :2] = xy
    pos = np.zeros((rows, 3))
    pos[0, :2] = desired[0, :2] + (0.004, -0.003)
    for k in range(1, rows):
        pos[k, :2] = pos[k - 1, :2] + 0.08 * (desired[k, :2] - pos[k - 1, :2])
    true = pos.copy()
    pos[:, :2] += rng.normal(0.0, 2e-4, (rows, 2))
    phi = np.clip(np.cumsum(rng.normal(0.0, 0.02, (rows, 2)), axis=0) + 0.5, 0.0, 1.0)
    ran = np.arange(rows) >= first
    return closed_loop.TickLog(
        ran, pos, desired, phi, (phi <= 0.0).any(axis=1) | (phi >= 1.0).any(axis=1), true
    )


def test_edge_cases_match_the_python_metrics() -> None:
    """Steps of every length (one tick, shorter than the 2 s window, ending at the run's end), a
    setpoint reached exactly at its change, steps never reached or never settled, a window cut short
    by the end of the log, a law that never ran, non-finite measured or true positions; each run of
    the batch with its own steps."""
    rng = np.random.default_rng(4)
    spec = synthetic_spec()
    logs = [
        synthetic_log(
            rng, 5, [(0, (0.0, 0.12)), (5 + 200, (0.005, 0.128)), (5 + 260, (-0.004, 0.125))]
        ),
        synthetic_log(
            rng,
            3,
            [
                (0, (0.0, 0.12)),
                (100, (0.002, 0.121)),
                (101, (0.003, 0.122)),
                (102, (0.0, 0.12)),
                (300, (0.006, 0.13)),
                (N_EVAL + 2, (0.0, 0.124)),
            ],
        ),
        # the window runs past the log's end
        synthetic_log(rng, 40, [(0, (0.0, 0.12)), (200, (0.004, 0.126))]),
        synthetic_log(rng, N_EVAL + 10, [(0, (0.0, 0.12)), (100, (0.004, 0.126))]),  # never ran
    ]
    exact = synthetic_log(rng, 5, [(0, (0.0, 0.12)), (205, (0.005, 0.128)), (405, (0.001, 0.121))])
    exact.chiee[205, :2] = exact.chiee_des[205, :2]  # e0 = 0: t_r = 0
    # the last tick of a step outside: t_s NaN
    exact.chiee[400:405, :2] = exact.chiee_des[400:405, :2] + 0.02
    logs.append(exact)
    far = synthetic_log(rng, 5, [(0, (0.0, 0.12)), (105, (0.02, 0.14)), (305, (0.0, 0.12))])
    far.chiee[105:305, :2] = far.chiee_des[105:305, :2] + 0.03  # never reached, and unstable
    far.true_chiee[105:305, :2] = far.chiee[105:305, :2]
    logs.append(far)
    cycling = synthetic_log(rng, 5, [(0, (0.0, 0.12)), (205, (0.005, 0.128))])
    t = np.arange(cycling.true_chiee.shape[0]) * PERIOD_MS * 1e-3
    cycling.true_chiee[:, 0] += 1.5e-3 * np.sin(2 * np.pi * 11.0 * t)
    logs.append(cycling)
    nan_measured = synthetic_log(rng, 5, [(0, (0.0, 0.12)), (205, (0.005, 0.128))])
    nan_measured.chiee[300, 1] = np.nan  # evaluate refuses it; classify uses the true position
    logs.append(nan_measured)
    nan_true = synthetic_log(rng, 5, [(0, (0.0, 0.12)), (205, (0.005, 0.128))])
    nan_true.true_chiee[-1, 0] = np.inf
    logs.append(nan_true)
    got = assert_batch_matches(spec, logs)
    assert got.finite.tolist() == [True] * 7 + [False, True] and got.n_ticks[2] < N_EVAL
    assert got.unstable.tolist() == [False] * 5 + [True, False, False, True]
    assert got.limit_cycle[6] and not got.limit_cycle[3] and got.n_not_reached[5] == 1

"""hsa_core.sim.run_conditions: a profile's or a real run's conditions as the lockstep graph's
launch arguments, a real run's schedule for the sequencer, and the September 2023 tick estimator
(expected values from profiles.yaml, runs.yaml and a hand-built cubic, not from the code under
test)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hsa_core.model.params import load_params
from hsa_core.runs.profiles import load_profile
from hsa_core.runs.reference import load_run
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.sim.run_conditions import (
    TickEstimator,
    graph_arguments,
    plant_params,
    run_disturbance,
    run_schedule,
    tick_rates,
    tick_take,
    tick_window,
)


def test_a_profile_becomes_the_graphs_launch_arguments() -> None:
    assert graph_arguments(load_profile("lab")) == {
        "rate": "40.0",
        "integrator_dt": "0.0",
        "velocity_estimator": "savitzky_golay_20",
        "payload": "0.0",
        "sigma_a_eq": "[]",
        "plant_sigma_a_eq": "[]",
        "command_latency": "0.0",
        "command_queue_depth": "0",
        "command_transaction": "0.0",
    }
    sep = graph_arguments(load_profile("sep2023"), sigma_a_eq=(0.98, 1.01), payload=0.2)
    assert 1000.0 / float(sep["rate"]) == pytest.approx(36.0, abs=1e-12)  # the period in whole ms
    assert sep | {"rate": ""} == {
        "rate": "",
        "integrator_dt": "0.025",
        "velocity_estimator": "smoothing_spline_16",
        "payload": "0.2",
        "sigma_a_eq": "[0.98, 1.01]",
        "plant_sigma_a_eq": "[]",
        "command_latency": "0.0",
        "command_queue_depth": "10",
        "command_transaction": "0.016",
    }
    plant = graph_arguments(
        load_profile("lab"), sigma_a_eq=(1.0, 1.0), plant_sigma_a_eq=(1.03, 1.02)
    )
    assert (plant["sigma_a_eq"], plant["plant_sigma_a_eq"]) == ("[1.0, 1.0]", "[1.03, 1.02]")


def test_a_command_latency_adds_to_the_world_s_actuation_latency_only() -> None:
    world = DisturbanceModel(actuation_latency=0.002, servo_time_constant=0.01)
    run = run_disturbance(world, 0.011)
    assert run.actuation_latency == pytest.approx(0.013)
    assert run == DisturbanceModel(
        actuation_latency=run.actuation_latency, servo_time_constant=0.01
    )
    assert run_disturbance(world, 0.0) is world
    with pytest.raises(ValueError, match="command_latency must be >= 0 s"):
        run_disturbance(world, -0.001)


def test_a_command_queue_is_the_world_s_command_path_only() -> None:
    world = DisturbanceModel(actuation_latency=0.05)
    run = run_disturbance(world, 0.0, command_queue=(10, 0.016))
    assert (run.command_queue_depth, run.command_transaction) == (10, 0.016)
    assert dataclasses.replace(run, command_queue_depth=0, command_transaction=0.0) == world
    assert run_disturbance(run, 0.005).command_queue_depth == 10  # a latency keeps the queue
    with pytest.raises(ValueError, match="command_transaction must be a whole number of ms"):
        run_disturbance(world, 0.0, command_queue=(10, 0.0155))
    with pytest.raises(ValueError, match="command_queue_depth must be a whole number >= 0"):
        DisturbanceModel(command_queue_depth=-1)


def test_a_plant_sigma_shift_moves_the_plant_s_rest_strains_only() -> None:
    world = DisturbanceModel(rest_strain_offset=0.005, rest_strain_difference=0.002)
    run = run_disturbance(world, 0.0, (0.01, 0.03))
    # rod 1: 0.005 - 0.001 + 0.01, rod 2: 0.005 + 0.001 + 0.03 (plant_params' split of the two)
    plant = run.plant_params(load_params("fpu"))
    nominal = np.asarray(load_params("fpu").sigma_a_eq)
    np.testing.assert_allclose(plant.sigma_a_eq - nominal, [0.014, 0.036], atol=1e-12)
    assert dataclasses.replace(run, rest_strain_offset=0.005, rest_strain_difference=0.002) == world
    with pytest.raises(ValueError, match="rest_strain_shift must be finite"):
        run_disturbance(world, 0.0, (float("nan"), 0.0))


def test_a_real_run_brings_its_own_conditions_and_step_instants() -> None:
    run = load_run("20231019_143126")
    args = graph_arguments(load_profile("lab"), run=run)
    assert args["material"] == "epu" and args["controller"] == "psatid"
    # oct2023
    assert args["velocity_estimator"] == "savitzky_golay_20" and args["integrator_dt"] == "0.025"
    assert args["command_latency"] == "0.006"
    sigma = run.conditions.sigma_a_eq
    assert args["sigma_a_eq"] == f"[{sigma[0]!r}, {sigma[1]!r}]"
    schedule = run_schedule(run)
    assert schedule["times"][0] == 0.0 and schedule["times"][1:] == pytest.approx(
        list(run.step_instants)
    )
    assert len(schedule["points"]) == 2 * len(schedule["times"]) == 22
    assert schedule["times"][-1] + 1.0 / schedule["rate"] == pytest.approx(run.t[-1] + 0.01)


def test_the_tick_estimator_differentiates_a_cubic_after_sixteen_ticks() -> None:
    estimator = TickEstimator(0.036)
    # the newest sample's stamp wanders with the mocap grid
    t = np.arange(20) * 0.036 + np.array([0.0, 0.004] * 10)
    coeffs = np.array([0.1, -0.5, 2.0, 0.3])  # x = c0 + c1 t + c2 t^2 + c3 t^3 in every coordinate
    results = []
    for k, tk in enumerate(t):
        x = np.polyval(coeffs[::-1], tk) * np.ones(6)
        results.append(estimator.update(int(round(tk * 1e9)) + 5_000_000_000, x[:3], x[3:]))
        if k == 3:
            # same stamp
            assert estimator.update(int(round(tk * 1e9)) + 5_000_000_000, x[:3], x[3:]) is None
    assert all(r is None for r in results[:15]) and all(r is not None for r in results[15:])
    slope = coeffs[1] + 2 * coeffs[2] * t[-1] + 3 * coeffs[3] * t[-1] ** 2
    np.testing.assert_allclose(np.concatenate(results[-1]), slope, rtol=1e-7)


def test_the_batched_loop_s_traced_window_is_the_tick_estimator() -> None:
    """One definition of the September window: tick_take/tick_rates traced with jax.numpy (as the
    batched loop runs them) give, tick by tick, what TickEstimator gives, through a repeated stamp,
    a non-finite state and a gap that restarts the count."""
    import jax
    import jax.numpy as jnp

    period = 0.036
    stamps = list(np.arange(18) * period)
    stamps[5] = stamps[4]  # no new sample at this tick
    stamps += list(stamps[-1] + 0.2 + np.arange(17) * period)  # a 0.236 s gap (> 5 periods)
    rng = np.random.default_rng(3)
    states = rng.normal(size=(len(stamps), 6))
    states[9, 2] = np.nan
    estimator = TickEstimator(period)
    take = jax.jit(lambda w, t, z: tick_take(w, t, z, period, jnp))
    rates = jax.jit(lambda w: tick_rates(w, jnp))
    window, ready = tick_window(jnp), []
    for stamp, z in zip(stamps, states):
        expected = estimator.update(int(round(stamp * 1e9)) + 7_000_000_000, z[:3], z[3:])
        window, taken = take(window, stamp, z)
        derivative, full = rates(window)
        assert (expected is not None) == bool(taken & full)
        if expected is not None:
            np.testing.assert_allclose(np.concatenate(expected), derivative, rtol=1e-9, atol=1e-9)
        ready.append(expected is not None)
    # 16 distinct finite states from the 18th tick; none right after the gap; 16 again at its end
    assert ready.index(True) == 17 and not any(ready[18:33]) and ready[33:] == [True, True]


def test_a_payload_is_the_plants_only_at_the_papers_payload_cog() -> None:
    model = load_params("fpu")
    assert plant_params(model, 0.0) is model
    plant = plant_params(model, 0.15)
    assert float(plant.m_pl) == 0.15
    np.testing.assert_array_equal(plant.CoG_pl, [0.0, -0.0255])  # model.md §2, payload runs
    np.testing.assert_array_equal(model.CoG_pl, [0.0, 0.0])

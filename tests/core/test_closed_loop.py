"""The JAX closed loop (hsa_core.sim.closed_loop) against the offline experiment it must reproduce,
and its batching."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from functools import partial

import jax
import numpy as np
import pytest

from hsa_core.controller.control import CollocatedGains, default_gains
from hsa_core.model.params import load_params
from hsa_core.runs import profiles, reference
from hsa_core.sim import closed_loop
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.sim.experiment import ExperimentConfig, profile_config, replay_config, run_experiment
from hsa_core.task.trajectories import TimedReference, step_reference

RTOL = 1e-6


def short(material: str = "fpu", seconds: float = 10.0) -> TimedReference:
    """The material's step list cut to its first ``seconds`` (one step per 10 s)."""
    ref = step_reference(material)
    keep = ref.t < seconds
    return TimedReference(ref.t[keep], ref.p_des[keep], ref.name, seconds)


def metric_values(m) -> np.ndarray:
    """RMSE, saturation, mean t_r, t_s, overshoot and e_ss of a RunMetrics, as one vector."""
    return np.array(
        [
            m.rmse,
            m.saturated_fraction,
            m.response_time_mean,
            m.settling_time_mean,
            m.overshoot_mean,
            m.steady_state_error_mean,
            m.n_ticks,
        ]
    )


@pytest.mark.parametrize(
    "law, ee_integral", [("psatid", False), ("pid", False), ("psatid_gc", True)]
)
def test_the_jax_loop_reproduces_the_offline_experiment(law: str, ee_integral: bool) -> None:
    # e_ss of 3 steps compared
    config = ExperimentConfig("fpu", law, ee_integral, reference=short(seconds=40.0))
    offline = run_experiment(config)
    spec, inputs, constants = closed_loop.prepare(config)
    log = closed_loop.compiled(spec, inputs, constants)
    got = closed_loop.evaluate(spec, log, config.name)
    ran = np.asarray(log.ran)
    first = int(np.argmax(ran))
    chiee = np.asarray(log.chiee)[first : first + spec.n_eval]
    assert chiee.shape == offline.log.chiee.shape
    np.testing.assert_allclose(chiee, offline.log.chiee, rtol=0, atol=1e-9)  # tick by tick
    assert np.all(np.isfinite(metric_values(offline.metrics)))
    np.testing.assert_allclose(metric_values(got), metric_values(offline.metrics), rtol=RTOL)


def assert_equal_to_the_offline_experiment(config: ExperimentConfig) -> closed_loop.TickLog:
    """The batched loop of ``config`` equals run_experiment tick by tick (1e-9 m) and in its
    metrics; its log."""
    offline = run_experiment(config)
    spec, inputs, constants = closed_loop.prepare(config)
    log = closed_loop.compiled(spec, inputs, constants)
    first = int(np.argmax(np.asarray(log.ran)))
    chiee = np.asarray(log.chiee)[first : first + spec.n_eval]
    assert chiee.shape == offline.log.chiee.shape
    np.testing.assert_allclose(chiee, offline.log.chiee, rtol=0, atol=1e-9)
    true_chiee = np.asarray(log.true_chiee)[first : first + spec.n_eval]
    np.testing.assert_allclose(true_chiee, offline.true_chiee, rtol=0, atol=1e-9)
    got = closed_loop.evaluate(spec, log)
    np.testing.assert_allclose(metric_values(got), metric_values(offline.metrics), rtol=RTOL)
    return log


def test_a_september_replay_with_a_payload_equals_the_offline_experiment() -> None:
    """The September 2023 run's own conditions (36 ms period, 25 ms integrator step, the spline
    stand-in estimator,
    its σ_a,eq, its real step instants) plus a payload: the batched loop runs them as
    run_experiment does."""
    run = reference.load_run("20230925_093236")
    config = replay_config(run, payload=0.1)
    ref = config.reference
    keep = ref.t < 15.0  # the start and the first real step (at 9.87 s)
    cut = TimedReference(ref.t[keep], ref.p_des[keep], ref.name, 15.0)
    config = dataclasses.replace(config, reference=cut)
    assert config.profile == "sep2023" and config.payload == 0.1 and len(config.reference) == 2
    spec, _, _ = closed_loop.prepare(config)
    assert spec.velocity_estimator.value == "smoothing_spline_16" and spec.period_ms == 36
    assert_equal_to_the_offline_experiment(config)


def test_a_world_parameter_reaches_both_paths() -> None:
    """The servos' time constant and the damping factor are the world's (WorldParams / interval_fn),
    the actuation latency the world's goal queue: set in the DisturbanceModel, they change the
    offline experiment and the batched loop alike (a latency of more than two 25 ms periods: three
    goals in flight)."""
    config = ExperimentConfig("fpu", "psatid", reference=short(seconds=3.0))
    world = DisturbanceModel(servo_time_constant=0.04, damping_scale=2.0, actuation_latency=0.061)
    changed = dataclasses.replace(config, disturbance=world)
    assert closed_loop.prepare(changed)[0].goal_slots == 4
    before = np.asarray(closed_loop.compiled(*closed_loop.prepare(config)).true_chiee)
    after = np.asarray(assert_equal_to_the_offline_experiment(changed).true_chiee)
    assert np.max(np.abs(after - before)) > 1e-4  # it did change the world


def test_the_profile_s_command_latency_reaches_both_paths() -> None:
    """The October profile's command latency (tick → goal on the bus) adds to the world's
    actuation latency in the offline experiment and the batched loop alike (equal logs), and
    changes the run (in the declared world, whose own latency is 2 ms)."""
    october = profiles.load_profile("oct2023")
    config = profile_config(
        october, "fpu", "psatid", reference=short(seconds=2.0), disturbance=DisturbanceModel()
    )
    assert october.command_latency_ms > 0
    assert config.command_latency == pytest.approx(october.command_latency_ms * 1e-3)
    spec, inputs, constants = closed_loop.prepare(config)
    assert int(inputs.actuation_latency_ms) == 2 + october.command_latency_ms
    after = np.asarray(assert_equal_to_the_offline_experiment(config).true_chiee)
    without = inputs._replace(actuation_latency_ms=jax.numpy.asarray(2))  # the world's own only
    before = np.asarray(closed_loop.compiled(spec, without, constants).true_chiee)
    assert np.max(np.abs(after - before)) > 1e-5  # it did change the world


def test_the_september_command_queue_reaches_both_paths() -> None:
    """The September profile's command queue (depth 10, 16 ms transactions) delays goals that
    change at every tick (the task-space PID after a step) in the offline experiment and the
    batched loop alike (equal logs, a 61 ms world latency: many writes in flight); without it the
    run differs."""
    september = profiles.load_profile("sep2023")
    assert (september.command_queue_depth, september.command_transaction_ms) == (10, 16)
    world = DisturbanceModel(actuation_latency=0.061)
    # 12.6 s: a whole number of 36 ms ticks (the metrics' last step ends where the log does)
    config = profile_config(
        september, "fpu", "pid", reference=short(seconds=12.6), disturbance=world
    )
    assert config.world().command_queue_depth == 10
    spec, inputs, constants = closed_loop.prepare(config)
    assert (spec.queue_depth, spec.transaction_ms) == (10, 16)
    queued = np.asarray(assert_equal_to_the_offline_experiment(config).true_chiee)
    direct = dataclasses.replace(config, command_queue=(0, 0.0))
    assert closed_loop.prepare(direct)[0].queue_depth == 0
    without = np.asarray(closed_loop.compiled(*closed_loop.prepare(direct)).true_chiee)
    assert np.max(np.abs(queued - without)) > 1e-3  # the queue delays the step's goals


def test_a_plant_sigma_a_eq_reaches_both_paths_and_the_plant_only() -> None:
    """A run's plant σ_a,eq beyond the controller's model (ExperimentConfig.plant_sigma_a_eq, the
    PID replay) moves the plant's rest strains in the offline experiment and the batched loop
    alike (equal logs); the controller's model keeps its own (the declared world: one rest-strain
    offset for both rods)."""
    config = ExperimentConfig(
        "fpu",
        "pid",
        reference=short(seconds=2.0),
        plant_sigma_a_eq=(1.03, 1.02),
        disturbance=DisturbanceModel(),
    )
    spec, inputs, constants = closed_loop.prepare(config)
    nominal = np.asarray(load_params("fpu").sigma_a_eq)
    np.testing.assert_allclose(constants.model.sigma_a_eq, nominal)
    default = DisturbanceModel()
    np.testing.assert_allclose(
        inputs.plant.sigma_a_eq, np.array([1.03, 1.02]) + default.rest_strain_offset, atol=1e-12
    )
    after = np.asarray(assert_equal_to_the_offline_experiment(config).true_chiee)
    plain = closed_loop.prepare(dataclasses.replace(config, plant_sigma_a_eq=None))[1]
    before = np.asarray(closed_loop.compiled(spec, plain, constants).true_chiee)
    assert np.max(np.abs(after - before)) > 1e-4  # it did change the plant


def test_a_batch_of_gains_equals_the_runs_one_by_one() -> None:
    config = ExperimentConfig("fpu", "psatid", reference=short(seconds=10.0))
    spec, inputs, constants = closed_loop.prepare(config)
    gains = [default_gains("psatid"), CollocatedGains(kp=0.2, ki=0.1, kd=0.01, gamma=50.0)]
    batched = jax.tree_util.tree_map(lambda *v: np.stack(v), *gains)
    axes = closed_loop.LoopInputs(None, 0, None, None)
    logs = jax.jit(jax.vmap(partial(closed_loop.rollout, spec), in_axes=(axes, None)))(
        inputs._replace(gains=batched), constants
    )
    for i, g in enumerate(gains):
        one = run_experiment(dataclasses.replace(config, gains=g))
        got = closed_loop.evaluate(spec, jax.tree_util.tree_map(lambda a: a[i], logs))
        np.testing.assert_allclose(metric_values(got), metric_values(one.metrics), rtol=RTOL)


def test_a_batch_of_models_and_setpoints_equals_the_runs_one_by_one() -> None:
    """constant_axes batches the controller's model and its planned setpoints (as the feedforward
    bound needs)."""
    config = ExperimentConfig("fpu", "psatid", reference=short(seconds=10.0))
    nominal = closed_loop.prepare(config)[2].model
    models = [nominal, nominal.replace(C_eps=np.asarray(nominal.C_eps) * 1.05)]
    prepared = [closed_loop.prepare(config, model=m) for m in models]
    spec, inputs, _ = prepared[0]
    stacked = jax.tree_util.tree_map(lambda *v: np.stack(v), *[p[2] for p in prepared])
    constants = stacked._replace(ref_index=prepared[0][2].ref_index)
    logs = closed_loop.batch_rollout(
        spec,
        inputs,
        constants,
        closed_loop.LoopInputs(None, None, None, None),
        closed_loop.LoopConstants(0, 0, None),
    )
    rmse = []
    for i, (_, _, one_constants) in enumerate(prepared):
        one = closed_loop.evaluate(spec, closed_loop.compiled(spec, inputs, one_constants))
        got = closed_loop.evaluate(spec, jax.tree_util.tree_map(lambda a: a[i], logs))
        np.testing.assert_allclose(metric_values(got), metric_values(one), rtol=RTOL)
        rmse.append(got.rmse)
    assert rmse[0] != pytest.approx(rmse[1], rel=1e-3)  # the two models do steer differently


SHARDED = """
import json, sys
import jax, numpy as np
from hsa_core.jaxsetup import configure_jax
configure_jax()
from hsa_core.sim import closed_loop
from hsa_core.sim.experiment import ExperimentConfig
from hsa_core.task.trajectories import TimedReference, step_reference
ref = step_reference("fpu")
reference = TimedReference(ref.t[:1], ref.p_des[:1], ref.name, 3.0)
config = ExperimentConfig("fpu", "psatid", reference=reference)
spec, inputs, constants = closed_loop.prepare(config)
noise = np.stack([closed_loop.noise(config.base_world(), spec, seed=s) for s in range(4)])
axes = closed_loop.LoopInputs(None, None, 0, None)
logs = closed_loop.batch_rollout(spec, inputs._replace(noise=noise), constants, axes)
one = closed_loop.compiled(spec, inputs._replace(noise=noise[3]), constants)
runs = [jax.tree_util.tree_map(lambda a: a[i], logs) for i in range(4)]
rmse = [closed_loop.evaluate(spec, run).rmse for run in runs]
print(json.dumps({"devices": len(jax.devices()), "shards": len(logs.chiee.sharding.device_set),
                  "rmse": rmse, "one": closed_loop.evaluate(spec, one).rmse}))
"""


def test_the_batch_is_split_over_every_device() -> None:
    """Two host devices (XLA_FLAGS) stand in for two GPUs: each holds half the batch, results as on
    one device."""
    env = {
        **os.environ,
        "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
        "JAX_PLATFORMS": "cpu",
    }
    out = subprocess.run(
        [sys.executable, "-c", SHARDED], env=env, capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["devices"] == 2 and got["shards"] == 2
    assert len(set(got["rmse"])) == 4  # four seeds, four different runs
    assert got["rmse"][3] == pytest.approx(got["one"], rel=RTOL)


def test_the_run_s_sigma_a_eq_reaches_the_controller_s_model_and_the_plant() -> None:
    """σ_a,eq calibrated before a run (hsa_core.runs.reference conditions): the model's, and the
    plant's plus the declared world's offset."""
    config = ExperimentConfig(
        "fpu",
        "psatid",
        reference=short(seconds=10.0),
        sigma_a_eq=(1.02, 1.03),
        disturbance=DisturbanceModel(),
    )
    spec, inputs, constants = closed_loop.prepare(config)
    np.testing.assert_allclose(constants.model.sigma_a_eq, [1.02, 1.03])
    np.testing.assert_allclose(inputs.plant.sigma_a_eq, np.add([1.02, 1.03], 0.005))
    # default: nominal
    np.testing.assert_allclose(ExperimentConfig("fpu").model().sigma_a_eq, [1.0, 1.0])


def test_a_run_with_mocap_outages_is_refused() -> None:
    """The batched loop has no supervision faults; an outage run must go to run_experiment, not be
    silently lost."""
    with pytest.raises(ValueError, match="fault-free"):
        closed_loop.prepare(ExperimentConfig("fpu", "psatid", mocap_outages=((1.0, 1.5),)))

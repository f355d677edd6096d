"""The simulated world (hsa_core.sim.world): servo speed and latency, mocap timing and noise,
torque, the payload, and that the state does not depend on how a caller chops time into calls (the
offline experiment and the simulator chop it differently)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hsa_core.model import kinematics
from hsa_core.model.actuation import TICKS_PER_RAD, MotorMap, ServoModel
from hsa_core.model.params import load_params
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.sim.world import (
    GRID_NS,
    MOCAP_PERIOD_NS,
    World,
    hanging_at_rest,
    interval_fn,
    mocap_sample,
    payload_schedule,
    servo_speed,
    to_grid,
)
from hsa_core.task.planning import static_equilibrium

MS = 1_000_000
NEUTRAL = (2048, 2048, 2048, 2048)
SPEED = 55.0 / 60.0 * 4096  # MX-28 no-load speed [ticks/s], 55 rev/min at 12 V (e-Manual)


@pytest.fixture(scope="module")
def model():
    return load_params("fpu")


def world(model, disturbance: DisturbanceModel | None = None) -> World:
    return World(model, disturbance or DisturbanceModel(), MotorMap(NEUTRAL, phi_max=3.4))


def test_servo_moves_at_the_no_load_speed_and_stops_on_the_goal() -> None:
    servo = ServoModel()
    assert servo.max_speed_ticks_per_s == pytest.approx(SPEED)
    position, velocity = servo.step(0.0, 1000.0, 0.1)
    assert position == pytest.approx(0.1 * SPEED) and velocity == pytest.approx(SPEED)
    assert servo.step(0.0, 100.0, 0.1) == (100.0, 0.0)  # reaches it within dt: stops there
    assert servo.step(0.0, -1000.0, 0.1)[0] == pytest.approx(-0.1 * SPEED)
    assert ServoModel(max_speed_ticks_per_s=math.inf).step(0.0, 1e6, 1e-3) == (1e6, 0.0)


def test_a_goal_takes_effect_after_the_actuation_latency_then_moves_at_the_speed_cap(model) -> None:
    w = world(model)
    w.advance_to(10 * MS)
    w.write_goals(w.motor_map.goal_ticks([1.0, 1.0]))  # at 10 ms; the declared latency is 2 ms
    w.advance_to(12 * MS)
    np.testing.assert_array_equal(w.position, NEUTRAL)  # not yet
    w.advance_to(22 * MS)
    np.testing.assert_allclose(np.abs(w.position - NEUTRAL), 10e-3 * SPEED, rtol=1e-12)
    np.testing.assert_allclose(np.abs(w.velocity), SPEED, rtol=1e-9)
    # both rods twist forward
    np.testing.assert_allclose(w.twists(), 10e-3 * SPEED / TICKS_PER_RAD, rtol=1e-12)
    np.testing.assert_array_equal(w.present_ticks(), np.rint(w.position))


def test_torque_off_freezes_the_shafts(model) -> None:
    w = world(model)
    w.write_goals(np.asarray(NEUTRAL) + 1000)
    w.advance_to(7 * MS)
    w.set_torque([False, True, False, True])
    before = w.position.copy()
    w.advance_to(17 * MS)
    np.testing.assert_array_equal(w.position[[0, 2]], before[[0, 2]])
    assert np.all(w.position[[1, 3]] > before[[1, 3]])


def test_mocap_samples_every_5_ms_available_after_the_latency(model) -> None:
    w = world(model)
    assert w.next_sample_ns() == 6 * MS  # stamp 0 + 6 ms measurement latency
    w.advance_to(30 * MS)
    samples = w.take_samples(21 * MS)
    assert [s.stamp_ns for s in samples] == [0, 5 * MS, 10 * MS, 15 * MS]
    assert [s.available_ns for s in samples] == [6 * MS, 11 * MS, 16 * MS, 21 * MS]
    assert w.next_sample_ns() == 26 * MS
    ideal = world(model, DisturbanceModel.none())
    ideal.advance_to(1 * MS)
    (first,) = ideal.take_samples(0)
    assert first.available_ns == 0
    truth = World(model, DisturbanceModel.none(), MotorMap(NEUTRAL, phi_max=3.4)).true_pose()
    np.testing.assert_array_equal(first.chiee, truth)  # no noise: the plant's pose


def test_the_seed_fixes_the_noise(model) -> None:
    runs = []
    for seed in (0, 0, 1):
        w = world(model, DisturbanceModel(seed=seed))
        w.advance_to(50 * MS)
        runs.append(np.array([s.chiee for s in w.take_samples(50 * MS)]))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])
    assert 1e-5 < np.std(runs[0][:, 0]) < 1e-3  # σ = 0.1 mm declared


def test_the_state_does_not_depend_on_how_time_is_chopped(model) -> None:
    """The simulator advances in instants of 1-20 ms, the offline experiment in others: same state,
    bit for bit."""
    goals = {3 * MS: 700, 27 * MS: -300, 41 * MS: 1500}
    states = []
    for steps in (
        [97 * MS],
        list(range(MS, 98 * MS, MS)),
        [6 * MS, 25 * MS, 26 * MS, 50 * MS, 97 * MS],
    ):
        w = world(model)
        times = sorted(set(steps) | set(goals))
        for t in times:
            w.advance_to(t)
            if t in goals:
                w.write_goals(np.asarray(NEUTRAL) + goals[t], t)
        w.advance_to(97 * MS)
        states.append(
            (np.asarray(w.x), w.position.copy(), [s.chiee for s in w.take_samples(97 * MS)])
        )
    for x, position, samples in states[1:]:
        np.testing.assert_array_equal(x, states[0][0])
        np.testing.assert_array_equal(position, states[0][1])
        np.testing.assert_array_equal(samples, states[0][2])


def test_the_world_runs_its_pure_interval(model) -> None:
    """One definition of a world interval (hsa_core.sim.world.interval_fn, which the batched loop
    calls too): stepping it by hand from the world's start with the World's parameters gives the
    World's state."""
    w = world(model)
    goal = np.asarray(NEUTRAL, dtype=float) + [700, -300, 1500, 20]
    w.write_goals(goal, 0)  # in force from 2 ms (the actuation latency)
    w.advance_to(12 * MS)
    interval = jax.jit(interval_fn(w.params))
    x, position = jnp.asarray(hanging_at_rest(w.plant)), jnp.asarray(NEUTRAL, dtype=float)
    for k in range(12):
        x, position = interval(
            x, position, goal if k >= 2 else jnp.asarray(NEUTRAL, dtype=float), np.ones(4, bool)
        )
    np.testing.assert_array_equal(np.asarray(position), w.position)
    # jit boundaries: last bits
    np.testing.assert_allclose(np.asarray(x), np.asarray(w.x), rtol=1e-13, atol=1e-15)
    assert (
        w.params.servo_speed
        == servo_speed(DisturbanceModel().servo_max_speed)
        == pytest.approx(SPEED / 1000)
    )
    np.testing.assert_array_equal(
        w.true_pose(), np.asarray(mocap_sample(w.plant, w.x, np.zeros(3)))
    )


def test_goal_offsets_traced_are_the_driver_s_goal_ticks() -> None:
    """The batched loop writes goals with MotorMap.goal_offsets under jax.numpy: the driver's ticks,
    whole ticks too."""
    motor_map = MotorMap(NEUTRAL, phi_max=3.4)
    phis = [
        [0.0, 0.0],
        [1.0, 2.5],
        [3.4, 0.3],
        [1024 / TICKS_PER_RAD, 7 / TICKS_PER_RAD],  # incl. whole-tick angles
    ]
    for phi in phis:
        want = motor_map.goal_ticks(phi) - np.asarray(NEUTRAL)
        np.testing.assert_array_equal(motor_map.goal_offsets(phi), want)
        np.testing.assert_array_equal(
            np.asarray(jax.jit(lambda p: motor_map.goal_offsets(p, jnp))(jnp.asarray(phi))), want
        )


def test_grid_rounding() -> None:
    assert to_grid(0) == 0 and to_grid(1) == GRID_NS and to_grid(GRID_NS) == GRID_NS
    assert MOCAP_PERIOD_NS == 5 * GRID_NS


def test_without_latency_a_sample_is_available_at_its_own_instant(model) -> None:
    """DisturbanceModel.none(): the sample of instant t is there once the world reached t (the
    offline loop waits on next_sample_ns and must move on)."""
    w = world(model, DisturbanceModel.none())
    assert w.next_sample_ns() == 0
    assert [s.stamp_ns for s in w.take_samples(0)] == [0]
    assert w.next_sample_ns() == 5 * MS
    w.advance_to(5 * MS)
    assert [s.stamp_ns for s in w.take_samples(5 * MS)] == [5 * MS]


# kg, a mass of the identification campaign (hsa_identification/config/campaign_example.yaml)
PAYLOAD = 0.437


def test_a_payload_lowers_the_resting_platform_to_its_equilibrium_and_its_removal_restores_the_pose(
    model,
) -> None:
    """At rest with φ = 0: the loaded world settles where the statics of the loaded model say (an
    independent Newton solve of G + K − α = 0), lower than the unloaded pose; taking the payload off
    returns to the unloaded pose."""
    w = world(model, DisturbanceModel.none())
    rest = w.true_pose()
    assert float(w.plant.m_pl) == 0.0  # the packaged set carries no payload
    w.set_payload(PAYLOAD, 100 * MS)
    w.advance_to(6000 * MS)
    assert float(w.plant.m_pl) == PAYLOAD
    loaded = model.replace(m_pl=PAYLOAD)
    q_eq, residual = static_equilibrium(loaded, np.zeros(2), np.asarray(w.x[:3]))
    assert float(residual) < 1e-9
    expected = np.asarray(kinematics.end_effector_pose(loaded, q_eq))
    np.testing.assert_allclose(w.true_pose(), expected, atol=1e-6)
    assert expected[1] > rest[1] + 1e-4, (
        "a payload must lower the platform (the robot hangs: +y is down)"
    )
    w.set_payload(0.0)
    w.advance_to(12000 * MS)
    np.testing.assert_allclose(w.true_pose(), rest, atol=1e-6)


def test_a_payload_takes_effect_at_its_grid_instant_without_recompiling(model) -> None:
    """Set for 7 ms + 1 ns, the mass acts from the 8 ms grid instant on: bit for bit unloaded until
    then; later changes of the mass reuse the one compiled plant segment."""
    loaded, free = world(model, DisturbanceModel.none()), world(model, DisturbanceModel.none())
    loaded.set_payload(PAYLOAD, 7 * MS + 1)
    for w in (loaded, free):
        w.advance_to(8 * MS)
    np.testing.assert_array_equal(np.asarray(loaded.x), np.asarray(free.x))
    for w in (loaded, free):
        w.advance_to(9 * MS)
    assert np.asarray(loaded.x)[4] != np.asarray(free.x)[4]  # the axial strain rate reacts first
    for k, mass in enumerate((0.2, 0.0, 0.637, 0.1)):
        loaded.set_payload(mass, (20 + 3 * k) * MS)
    loaded.advance_to(40 * MS)
    assert loaded._segment._cache_size() == 1


def test_later_of_two_payload_events_at_one_instant_wins(model) -> None:
    w = world(model, DisturbanceModel.none())
    w.set_payload(0.5, 10 * MS)
    w.set_payload(0.2, 9 * MS + 1)  # the same grid instant, set later
    w.advance_to(11 * MS)
    assert float(w.plant.m_pl) == 0.2
    with pytest.raises(ValueError, match=">= 0 kg"):
        w.set_payload(-0.1)


def test_payload_schedule_parses_flat_pairs_and_refuses_malformed_ones() -> None:
    assert payload_schedule([]) == ()
    assert payload_schedule([0.0, 0.0, 1.5, 0.437, 2.0, 0.0]) == (
        (0, 0.0),
        (1_500_000_000, 0.437),
        (2 * 10**9, 0.0),
    )
    for bad, reason in (
        ([1.0], "pairs"),
        ([1.0, 0.1, 1.0, 0.2], "increasing"),
        ([2.0, 0.1, 1.0, 0.2], "increasing"),
        ([-1.0, 0.1], ">= 0 s"),
        ([1.0, -0.1], ">= 0 kg"),
        ([1.0, math.nan], "finite"),
    ):
        with pytest.raises(ValueError, match=reason):
            payload_schedule(bad)

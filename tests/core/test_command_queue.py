"""The September command path (hsa_core.sim.command_queue) and the world that runs it: per-motor
topics on change, one driver thread, one transaction at a time. Expected times are worked out by
hand from the model's rules (module docstring)."""

from __future__ import annotations

import numpy as np
import pytest

from hsa_core.model.actuation import MotorMap
from hsa_core.model.params import load_params
from hsa_core.sim import command_queue as cq
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.sim.world import World

MS = 1_000_000
NEUTRAL = (2048.0, 2048.0, 2048.0, 2048.0)


def serve(state: cq.QueueState, until_ms: int) -> tuple[cq.QueueState, list[tuple[int, list]]]:
    """Every cycle that starts before ``until_ms``: (write time [ms], goals in force) in order."""
    writes = []
    while cq.has_work(state) and state.cursor < until_ms:
        state, done = cq.cycle(state, 16)
        writes += [(int(done.at[m]), done.vectors[m].tolist()) for m in np.flatnonzero(done.wrote)]
    return state, writes


def test_a_jump_from_rest_is_written_motor_by_motor_then_the_poll() -> None:
    state = cq.publish(cq.initial([0.0, 0.0], depth=10), [5.0, 7.0], 100)
    state, writes = serve(state, 136)
    assert writes == [(100, [5.0, 0.0]), (116, [5.0, 7.0])]
    assert int(state.cursor) == 148 and int(state.polls) == 0  # 2 writes and a poll: 48 ms


def test_an_unchanged_goal_sends_only_a_poll() -> None:
    state = cq.publish(cq.initial([3.0, 4.0], depth=10), [3.0, 4.0], 50)
    state, writes = serve(state, 1000)
    assert writes == [] and int(state.cursor) == 66


def test_goals_that_change_every_tick_fall_behind() -> None:
    """Two motors, a 36 ms tick and 48 ms of work per tick (2 writes and a poll): each tick's goals
    are written 12 ms later than the previous tick's."""
    state = cq.initial([0.0, 0.0], depth=2)
    writes = []
    for k in range(1, 5):  # ticks at 0, 36, 72, 108 ms publish goals k, 10 k
        state, done = serve(state, 36 * (k - 1))
        writes += done
        state = cq.publish(state, [float(k), 10.0 * k], 36 * (k - 1))
    state, done = serve(state, 10_000)
    writes += done
    # cycles at 0, 48, 96, 144: 0, 12, 24, 36 ms after their tick
    assert [t for t, _ in writes] == [0, 16, 48, 64, 96, 112, 144, 160]
    assert [g for _, g in writes][1::2] == [[1, 10], [2, 20], [3, 30], [4, 40]]
    assert [g for _, g in writes][0::2] == [[1, 0], [2, 10], [3, 20], [4, 30]]
    assert int(state.cursor) == 192


def test_a_full_topic_drops_its_oldest_goal() -> None:
    state = cq.initial([0.0], depth=2)
    for k, t in enumerate((0, 1, 2), start=1):  # three goals before the driver is free again
        state = cq.publish(state, [float(k)], t)
        if k == 1:
            state, _ = cq.cycle(state, 16)  # the first is written at 0; busy until 32 (poll)
    state, writes = serve(state, 10_000)
    assert [g for _, g in writes] == [[2.0], [3.0]]
    state = cq.publish(state, [4.0], 200)
    state = cq.publish(state, [5.0], 201)
    state = cq.publish(state, [6.0], 202)  # depth 2: goal 4 is dropped
    _, writes = serve(state, 10_000)
    assert [g for _, g in writes] == [[5.0], [6.0]]


def test_the_world_writes_each_motor_s_goal_when_the_driver_gets_to_it() -> None:
    world = World(
        load_params("fpu"),
        DisturbanceModel(
            actuation_latency=0.002, command_queue_depth=10, command_transaction=0.016
        ),
        MotorMap(NEUTRAL, phi_max=3.4),
    )
    world.advance_to(10 * MS)
    goal = np.asarray(NEUTRAL) + [100.0, 200.0, 300.0, 400.0]
    world.write_goals(goal)  # published at 10 ms: written at 10, 26, 42, 58 ms, in force 2 ms later
    # (the state after advance_to(t) is that of instant t: a goal in force at t moves it after t)
    for t_ms, in_force in ((12, 0), (13, 1), (28, 1), (29, 2), (45, 3), (60, 3), (61, 4)):
        world.advance_to(t_ms * MS)
        expected = np.where(np.arange(4) < in_force, goal, NEUTRAL)
        np.testing.assert_array_equal(world.goal, expected, err_msg=f"at {t_ms} ms")


@pytest.mark.parametrize("depth, transaction", [(10, 0.0155), (10, 0.0), (-1, 0.016)])
def test_a_command_queue_needs_a_depth_and_whole_milliseconds(
    depth: int, transaction: float
) -> None:
    with pytest.raises(ValueError, match="command_(queue_depth|transaction) must be a whole"):
        DisturbanceModel(command_queue_depth=depth, command_transaction=transaction)

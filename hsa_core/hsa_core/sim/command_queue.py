"""The September 2023 command path as a queue (no ROS): per-motor goal topics of bounded depth
served by one driver thread, one transaction at a time.

The original control node published each motor's goal on its own reliable keep-last-``depth`` topic,
only when it changed, and requested one position poll per tick; one driver thread served them in
turn, one blocking transaction (request and status round trip) each (spec reference_ros_graph.md §3
and §6 items 2–3, planning_and_control.md §7–8). Model, on the world's 1 ms grid:

* ``publish(t)``: a tick at ``t`` [ms] appends each changed goal to its motor's topic (a full topic
  drops its oldest goal) and one poll request (at most ``depth`` waiting);
* a **cycle** starts when the driver is free and has work, at the later of its last cycle's end
  and the work's arrival: one write per motor whose topic holds a goal (its oldest, in motor
  order), then one poll if any is waiting; each transaction lasts ``transaction_ms``. A write puts
  the whole goal vector then in force on the bus at its own start time.

The state is arrays and every step is written for ``xp`` = numpy or jax.numpy, so
:class:`hsa_core.sim.world.World` (cycle by cycle, as its time advances) and the batched loop
(:mod:`hsa_core.sim.closed_loop`, the cycles starting within each control period) run this one
definition. docs/simulation.md ("The September command queue") gives the evidence and what it does
to the replays.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np


class QueueState(NamedTuple):
    """The command path's state; goals in ticks, times in ms of the world's grid."""

    published: Any  # (motors,) the goal each motor's topic last received
    goals: Any  # (motors, depth) each topic's ring of waiting goals
    head: Any  # (motors,) index of each topic's oldest waiting goal
    length: Any  # (motors,) goals waiting per topic
    polls: Any  # () poll requests waiting
    cursor: Any  # () [ms] when the driver is free (the end of its last cycle)
    in_force: Any  # (motors,) the goals the driver last wrote


class Cycle(NamedTuple):
    """What one cycle wrote: per motor whether it wrote, when [ms], and the goal vector in force
    after that write."""

    wrote: Any  # (motors,) bool
    at: Any  # (motors,) [ms]
    vectors: Any  # (motors, motors)


def initial(goal: Any, depth: int, xp: Any = np) -> QueueState:
    """The empty path at rest with ``goal`` [ticks] published and in force (``depth`` >= 1)."""
    goal = xp.asarray(goal, dtype=xp.float64)
    n = goal.shape[0]
    zero = xp.zeros(n, dtype=xp.int32)
    return QueueState(
        goal,
        xp.zeros((n, depth), dtype=xp.float64),
        zero,
        zero,
        xp.asarray(0, dtype=xp.int32),
        xp.asarray(0, dtype=xp.int64),
        goal,
    )


def publish(state: QueueState, goal: Any, t_ms: Any, xp: Any = np) -> QueueState:
    """A tick at ``t_ms`` publishes ``goal`` [ticks] (each motor's only if it changed) and one poll
    request; the driver, if idle, is free from ``t_ms`` on."""
    depth = state.goals.shape[1]
    changed = xp.asarray(goal) != state.published
    full = state.length == depth
    head = xp.where(changed & full, (state.head + 1) % depth, state.head)
    length = xp.where(changed & ~full, state.length + 1, state.length)
    slot = (head + length - 1) % depth
    rows = xp.arange(state.goals.shape[0])
    current = state.goals[rows, slot]
    new = xp.where(changed, goal, current)
    if xp is np:
        goals = state.goals.copy()
        goals[rows, slot] = new
    else:
        goals = state.goals.at[rows, slot].set(new)
    return QueueState(
        xp.where(changed, goal, state.published),
        goals,
        head,
        length,
        xp.minimum(state.polls + 1, depth),
        xp.maximum(state.cursor, t_ms),
        state.in_force,
    )


def has_work(state: QueueState, xp: Any = np) -> Any:
    """Whether a goal or a poll is waiting."""
    return xp.any(state.length > 0) | (state.polls > 0)


def cycle(state: QueueState, transaction_ms: int, xp: Any = np) -> tuple[QueueState, Cycle]:
    """One cycle from ``state.cursor``: the oldest goal of every non-empty topic, in motor order,
    then one waiting poll; the driver is free again after its transactions."""
    depth = state.goals.shape[1]
    n = state.goals.shape[0]
    wrote = state.length > 0
    rows = xp.arange(n)
    oldest = state.goals[rows, state.head]
    rank = xp.cumsum(wrote) - wrote
    at = state.cursor + rank * transaction_ms
    # after motor m's write: the motors up to m that wrote have their new goal
    upto = (rows[None, :] <= rows[:, None]) & wrote[None, :]
    vectors = xp.where(upto, oldest[None, :], state.in_force[None, :])
    polled = state.polls > 0
    busy = (xp.sum(wrote) + polled) * transaction_ms
    return (
        QueueState(
            state.published,
            state.goals,
            xp.where(wrote, (state.head + 1) % depth, state.head),
            state.length - wrote,
            state.polls - polled,
            state.cursor + busy,
            xp.where(wrote, oldest, state.in_force),
        ),
        Cycle(wrote, at, vectors),
    )

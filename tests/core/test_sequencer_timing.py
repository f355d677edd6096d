"""hsa_core.task.sequencer_timing: the sequencer's first request falls on a supervision tick after
the start delay.

Hand-derived from the sequencer's state machine: tick k fires at k · 50 ms; tick 1 finds the planner
and sets start_at = 50 ms + start_delay; point 0 goes out at the first later tick k >= 2 with k · 50
ms >= start_at.
"""

from __future__ import annotations

import pytest

from hsa_core.task.sequencer_timing import SUPERVISION_PERIOD_NS, first_point_ns

MS = 1_000_000  # ns per ms


def test_supervision_period_is_50_ms():
    assert SUPERVISION_PERIOD_NS == 50 * MS


@pytest.mark.parametrize(
    ("start_delay", "expected_ms"),
    [
        (0.0, 100),  # start_at 50 ms is tick 1 itself: the request waits for tick 2
        (0.02, 100),  # start_at 70 ms → tick 2
        (0.05, 100),  # start_at 100 ms is exactly tick 2
        (0.06, 150),  # start_at 110 ms → tick 3
        (1.0, 1050),  # start_at 1050 ms is exactly tick 21
    ],
)
def test_first_point_is_the_first_later_tick_at_or_after_the_delay(start_delay, expected_ms):
    assert first_point_ns(start_delay) == expected_ms * MS

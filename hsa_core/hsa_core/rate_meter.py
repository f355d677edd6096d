"""Event rates per reporting period, from cumulative counters (the ``*_rate_hz``/``*_per_s`` values
on /diagnostics).

A node keeps its counters cumulative (received, published, cycles, …: they never reset, so nothing
is lost between reports) and, once per diagnostics period, asks a :class:`RateMeter` for the rate of
each counter since the previous report. Time is passed in explicitly as integer nanoseconds of one
clock (the node clock: wall time, or simulated time with ``use_sim_time``), so the meter is pure and
the same for every node.
"""

from __future__ import annotations

from collections.abc import Mapping


class RateMeter:
    """Rate [1/s] of each cumulative counter over the period since the previous reading (or the
    start)."""

    def __init__(self, start_ns: int) -> None:
        self._since_ns = start_ns
        self._base: dict[str, int] = {}

    def rates(self, now_ns: int, counts: Mapping[str, int]) -> dict[str, float]:
        """Per-second increase of each counter since the previous call, which ends the period at
        ``now_ns``.

        A counter not seen before counts from 0. A period of no time (a second report at the same
        instant, or a clock that went back) measures no rate: every rate is 0.
        """
        period = (now_ns - self._since_ns) * 1e-9
        rates = {
            name: (n - self._base.get(name, 0)) / period if period > 0.0 else 0.0
            for name, n in counts.items()
        }
        self._since_ns, self._base = now_ns, dict(counts)
        return rates

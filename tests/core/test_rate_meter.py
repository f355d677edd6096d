"""hsa_core.rate_meter: per-period rates of cumulative counters, with the time passed in as
nanoseconds."""

from __future__ import annotations

from hsa_core.rate_meter import RateMeter

S = 1_000_000_000  # ns per s


def test_rate_is_the_increase_over_the_period_since_the_start():
    meter = RateMeter(start_ns=5 * S)
    assert meter.rates(7 * S, {"received": 400, "published": 390}) == {
        "received": 200.0,
        "published": 195.0,
    }


def test_each_reading_starts_the_next_period_and_counts_from_its_totals():
    meter = RateMeter(start_ns=0)
    meter.rates(S, {"cycles": 100})
    # 100 → 150 cycles in 0.5 s
    assert meter.rates(S + S // 2, {"cycles": 150}) == {"cycles": 100.0}
    # nothing happened in the next 2 s
    assert meter.rates(S + S // 2 + 2 * S, {"cycles": 150}) == {"cycles": 0.0}


def test_a_counter_first_seen_later_counts_from_zero():
    meter = RateMeter(start_ns=0)
    meter.rates(S, {"reads": 10})
    assert meter.rates(2 * S, {"reads": 30, "writes": 4}) == {"reads": 20.0, "writes": 4.0}


def test_an_empty_period_measures_no_rate():
    meter = RateMeter(start_ns=3 * S)
    assert meter.rates(3 * S, {"ticks": 0}) == {"ticks": 0.0}
    assert meter.rates(3 * S, {"ticks": 2}) == {"ticks": 0.0}


def test_a_clock_that_went_back_measures_no_rate_and_restarts_the_period_there():
    meter = RateMeter(start_ns=10 * S)
    assert meter.rates(4 * S, {"ticks": 3}) == {"ticks": 0.0}
    assert meter.rates(5 * S, {"ticks": 43}) == {"ticks": 40.0}

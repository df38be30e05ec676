"""The forecast of the next frames (service/shell/arrivals.py), which times the snapshots."""
from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from service.shell.arrivals import FORGET_S, ArrivalForecast


def _periodic(f: ArrivalForecast, key: str, t0: float, period: float, n: int) -> float:
    for k in range(n):
        f.saw(key, t0 + k * period)
    return t0 + (n - 1) * period


def test_the_quiet_time_is_until_the_earliest_stream_is_due():
    f = ArrivalForecast()
    _periodic(f, "a", 10.000, 0.1, 10)  # last 10.9, due 11.0
    _periodic(f, "b", 10.030, 0.1, 10)  # last 10.93, due 11.03
    _periodic(f, "c", 10.020, 0.05, 20)  # last 10.97, due 11.02
    assert math.isclose(f.period("a"), 0.1) and math.isclose(f.period("c"), 0.05)
    assert math.isclose(f.quiet_for(10.975), 0.025)  # a, at 11.0
    assert f.quiet_for(11.0005) == 0.0  # a is overdue by half a millisecond: due now


def test_one_gap_or_one_burst_does_not_move_a_streams_period():
    f = ArrivalForecast()
    last = _periodic(f, "a", 0.0, 0.1, 6)
    f.saw("a", last + 1.5)  # an outage
    last = _periodic(f, "a", last + 1.6, 0.1, 3)
    f.saw("a", last + 0.001)  # a resent frame right behind
    assert math.isclose(f.period("a"), 0.1)


def test_floods_stopped_streams_and_streams_without_history_have_no_forecast():
    f = ArrivalForecast()
    _periodic(f, "flood", 0.0, 0.0005, 100)  # faster than any wearable publishes
    f.saw("new", 0.04)
    f.saw("new", 0.05)  # one interval only
    assert f.quiet_for(0.0502) == math.inf
    _periodic(f, "stopped", 0.0, 0.1, 10)  # last at 0.9, due at 1.0
    assert math.isclose(f.quiet_for(0.95), 0.05)
    assert f.quiet_for(1.06) == math.inf  # late by more than half a period: no cadence to keep clear of


def test_the_streams_followed_are_bounded_and_the_silent_ones_forgotten():
    f = ArrivalForecast(max_streams=50)
    for k in range(500):
        _periodic(f, f"r{k}", k * 0.001, 0.1, 4)
    assert len(f) == 50 and f.period("r499") is not None and f.period("r0") is None  # the least recently heard went
    f.quiet_for(0.5 + 0.3 + FORGET_S + 1.0)
    assert len(f) == 0


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 5), st.floats(0.0, 20.0)), max_size=60), st.floats(0.0, 20.0))
def test_the_quiet_time_is_never_negative_and_never_beyond_a_forecast_stream_s_period(arrivals, after):
    f = ArrivalForecast()
    for key, t in arrivals:
        f.saw(f"k{key}", t)
    quiet = f.quiet_for(max((t for _, t in arrivals), default=0.0) + after)  # asked after the arrivals it saw
    assert quiet >= 0.0
    periods = [p for p in (f.period(f"k{key}") for key in range(6)) if p is not None and 0.015 <= p <= 2.0]
    if quiet != math.inf:
        assert quiet <= max(periods) + 1e-9

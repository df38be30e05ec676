"""The robustness suite's perturbations (pdr/evaluation/perturb.py, robustness.py) on synthetic data."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pdr.evaluation import perturb as P
from pdr.evaluation.robustness import PERTURBATIONS, names_from, perturbed, verdict
from pdr.recording import Landmarks, Recording, Series


def _jittery_clock(rate_hz: float, duration_s: float, seed: int = 0) -> np.ndarray:
    """A phone's log: nominal rate, each sample up to 20 % of a period early or late."""
    n = int(duration_s * rate_hz)
    rng = np.random.default_rng(seed)
    return np.arange(n) / rate_hz + rng.uniform(-0.2, 0.2, n) / rate_hz


def _dominant_hz(t: np.ndarray, x: np.ndarray) -> float:
    rate = 1.0 / np.median(np.diff(t))
    spec = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(x.size)))
    return float(np.fft.rfftfreq(x.size, 1.0 / rate)[np.argmax(spec)])


@pytest.mark.parametrize("rate", [50.0, 60.0, 100.0, 200.0])
def test_resampling_a_sine_keeps_its_frequency_and_amplitude(rate):
    t = _jittery_clock(100.0, 20.0)
    v = np.sin(2 * np.pi * 2.0 * t)[:, None]  # 2 Hz: a walker's step rhythm
    nt, nv = P.resample(t, v, rate)
    assert np.allclose(np.diff(nt), 1.0 / rate)
    assert nt[0] == t[0] and nt[-1] <= t[-1]
    assert _dominant_hz(nt, nv[:, 0]) == pytest.approx(2.0, abs=0.06)
    inner = (nt > 1) & (nt < 19)  # away from the filter's ends
    assert np.max(np.abs(nv[inner, 0] - np.sin(2 * np.pi * 2.0 * nt[inner]))) < 0.05


def test_going_down_removes_what_the_new_rate_cannot_carry():
    """A 40 Hz tone at 200 Hz, taken to 50 Hz (Nyquist 25 Hz): without the low-pass it would alias
    to 10 Hz at full amplitude; with it, only a trace is left."""
    t = _jittery_clock(200.0, 10.0, seed=1)
    v = np.column_stack([np.sin(2 * np.pi * 40.0 * t), np.sin(2 * np.pi * 2.0 * t)])
    nt, nv = P.resample(t, v, 50.0)
    inner = (nt > 1) & (nt < 9)
    assert np.std(nv[inner, 0]) < 0.05 * np.std(v[:, 0])
    assert np.std(nv[inner, 1]) == pytest.approx(np.std(v[:, 1]), rel=0.05)  # the step band passes


def test_browser_stamps_are_late_increasing_and_a_few_ms_off():
    t = np.arange(6000) / 60.0
    s = P.browser_stamps(t, seed=3)
    assert np.all(np.diff(s) > 0)
    assert np.all(s >= t)
    delay = s - t
    assert 0.001 < np.median(delay) < 0.006
    assert np.mean(delay > 0.02) > 0.002  # some events late by tens of ms
    assert np.array_equal(s, P.browser_stamps(t, seed=3))  # seeded
    assert not np.array_equal(s, P.browser_stamps(t, seed=4))


def test_a_browser_timers_ticks_are_uneven_like_chromiums():
    """The intervals Chromium's devicemotion showed in the browser walk test: median 15.8 ms,
    5-95 % 10.4-24.1 ms, consecutive intervals anti-correlated (-0.28)."""
    t = P.timer_ticks(5.0, 125.0, 59.0, seed=[1, 2])
    d = np.diff(t)
    assert t[0] >= 5.0 and t[-1] <= 125.0 and np.all(d > 3e-3 - 1e-9)
    assert 57.0 < t.size / 120.0 < 59.5
    p5, p50, p95 = np.percentile(d, [5, 50, 95])
    assert 0.008 < p5 < 0.013 and 0.015 < p50 < 0.018 and 0.021 < p95 < 0.027
    assert -0.35 < np.corrcoef(d[:-1], d[1:])[0, 1] < -0.05
    assert np.mean(d > 0.035) > 0.002  # a busy page holds a tick back now and then
    assert np.array_equal(t, P.timer_ticks(5.0, 125.0, 59.0, seed=[1, 2]))
    assert not np.array_equal(t, P.timer_ticks(5.0, 125.0, 59.0, seed=[1, 3]))


def test_quantize_rounds_to_the_step():
    q = P.quantize(np.array([[0.04, 0.06, -0.16]]), 0.1)
    assert np.allclose(q, [[0.0, 0.1, -0.2]])


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 2, -1)])
def test_a_grip_rotation_keeps_vector_norms_and_turns_by_the_angle(axis):
    rng = np.random.default_rng(5)
    t = np.linspace(0, 10, 1001)
    v = rng.normal(size=(t.size, 3)) * 9.8
    th, dth = P.grip_angle(t, 4.0, math.pi / 2, turn_s=0.5)
    w = P.in_turned_phone(v, axis, th)
    assert np.allclose(np.linalg.norm(w, axis=1), np.linalg.norm(v, axis=1))
    before, after = t < 4.0, t >= 4.5
    assert np.array_equal(w[before], v[before])
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    # after the turn, the component along the axis is unchanged and the rest is turned by 90 deg
    assert np.allclose(w[after] @ a, v[after] @ a)
    vp, wp = v[after] - np.outer(v[after] @ a, a), w[after] - np.outer(w[after] @ a, a)
    assert np.allclose(np.einsum("ij,ij->i", vp, wp), 0.0, atol=1e-9)


def test_the_turns_gyro_transient_integrates_to_the_angle_and_is_consistent_with_the_vectors():
    """Integrating the perturbed gyro over the turn (still phone) gives the rotation that maps
    the old view of gravity onto the new one."""
    t = np.arange(0, 3, 0.001)
    th, dth = P.grip_angle(t, 1.0, math.radians(90), turn_s=0.5)
    assert np.trapezoid(dth, t) == pytest.approx(math.radians(90), abs=1e-4)
    g = np.tile([0.0, 0.0, 9.81], (t.size, 1))
    gyr = P.gyro_in_turned_phone(np.zeros((t.size, 3)), (0, 1, 0), th, dth)
    assert np.allclose(gyr[:, [0, 2]], 0) and gyr[:, 1].max() > 0
    # a still phone's gravity seen in the body frame obeys dg/dt = -ω × g
    acc = P.in_turned_phone(g, (0, 1, 0), th)
    dg = np.gradient(acc, t, axis=0)
    assert np.abs(dg).max() > 30 and np.allclose(dg, -np.cross(gyr, acc), atol=0.1)  # 0.1: the difference quotient at the ends


def test_held_in_another_attitude_comes_back():
    t = np.linspace(0, 10, 2001)
    th, _ = P.grip_angle(t, 3.0, 1.0, turn_s=0.5, back_s=6.0)
    assert np.all(th[t < 3.0] == 0) and np.allclose(th[(t > 3.5) & (t < 6.0)], 1.0) and np.allclose(th[t > 6.5], 0.0)


def test_bias_and_scale():
    v = np.ones((4, 3))
    assert np.allclose(P.with_bias(v, [0.1, 0, 0]), [[1.1, 1, 1]] * 4)
    assert np.allclose(P.with_scale(v, [1.02] * 3), 1.02)
    d = P.random_direction(7)
    assert np.linalg.norm(d) == pytest.approx(1.0) and np.array_equal(d, P.random_direction(7))


def test_steel_offsets_appear_and_vanish():
    t = np.linspace(0, 300, 30001)
    stretches = P.steel_stretches(0.0, 300.0, seed=2)
    assert len(stretches) >= 3
    mag = np.tile([20.0, 0.0, -40.0], (t.size, 1))
    out = P.near_steel(t, mag, stretches)
    offset = np.linalg.norm(out - mag, axis=1)
    inside = np.zeros(t.size, bool)
    for start, end, o in stretches:
        assert 20.0 <= np.linalg.norm(o) <= 50.0
        mid = (t > start + 1.0) & (t < end - 1.0)
        assert np.allclose(offset[mid], np.linalg.norm(o))
        inside |= (t > start) & (t < end)
    assert np.all(offset[~inside] == 0)  # vanishes between stretches


def test_a_gap_removes_exactly_the_samples_in_it():
    t = np.arange(0, 100, 0.01)
    windows = P.gap_windows(0.0, 100.0, seed=1)
    assert len(windows) == 3
    assert np.all((windows[:, 1] - windows[:, 0] >= 0.2) & (windows[:, 1] - windows[:, 0] <= 2.0))
    keep = P.outside_windows(t, windows)
    inside = np.zeros(t.size, bool)
    for a, b in windows:
        inside |= (t >= a) & (t < b)
    assert np.array_equal(keep, ~inside)
    assert (~keep).sum() == sum(np.count_nonzero((t >= a) & (t < b)) for a, b in windows)


def test_dropped_samples_are_about_the_fraction_and_seeded():
    keep = P.dropped(100000, 0.1, seed=9)
    assert 1 - keep.mean() == pytest.approx(0.1, abs=0.005)
    assert np.array_equal(keep, P.dropped(100000, 0.1, seed=9))


# --------------------------------------------------------------------------------------------
# On a whole recording
# --------------------------------------------------------------------------------------------
def _recording() -> Recording:
    t = _jittery_clock(100.0, 120.0)
    rng = np.random.default_rng(0)
    acc = np.column_stack([np.sin(2 * np.pi * 2 * t), np.zeros_like(t), 9.81 + np.cos(2 * np.pi * 2 * t)])
    gyr = rng.normal(0, 0.01, (t.size, 3))
    tm = np.arange(0, 120, 0.02)
    mag = np.tile([0.0, 20.0, -40.0], (tm.size, 1))
    tp = np.arange(0, 120, 0.2)
    lm = Landmarks(np.array([0.0, 60.0, 119.0]), np.zeros(3), np.zeros(3), np.zeros(3, int), np.arange(3))
    return Recording("walk_a.txt", "ipin", acc=Series(t, acc), gyr=Series(t, gyr), mag=Series(tm, mag),
                     pressure=Series(tp, np.full((tp.size, 1), 1000.0)), landmarks=lm)


@pytest.mark.parametrize("name", list(PERTURBATIONS))
def test_every_perturbation_gives_a_valid_reproducible_recording(name):
    rec = _recording()
    a, b = perturbed(rec, name), perturbed(rec, name)
    for s in ("acc", "gyr", "mag", "pressure"):
        sa, sb = getattr(a, s), getattr(b, s)
        assert np.all(np.diff(sa.t) > 0) and np.all(np.isfinite(sa.values)), s
        assert np.array_equal(sa.t, sb.t) and np.array_equal(sa.values, sb.values), s
    assert a.landmarks is rec.landmarks  # landmarks keep their times
    assert a.meta["perturbation"] == name
    assert np.array_equal(rec.acc.values, _recording().acc.values)  # the input is not modified
    changed = any(not np.array_equal(getattr(a, s).values, getattr(rec, s).values)
                  or not np.array_equal(getattr(a, s).t, getattr(rec, s).t) for s in ("acc", "gyr", "mag", "pressure"))
    assert changed


@pytest.mark.parametrize("name, angle", [("steep25", 25.0), ("flat30", -30.0)])
def test_a_phone_held_steeper_or_flatter_is_turned_about_x_from_the_first_sample(name, angle):
    """The whole-walk attitudes: every reading of gravity and of the field turned by the angle
    about the phone's x axis, from the first sample to the last, and no turn in the gyro."""
    rec = _recording()
    a = perturbed(rec, name)
    for s in ("acc", "mag"):
        before, after = getattr(rec, s).values, getattr(a, s).values
        cos = np.einsum("ij,ij->i", before[:, 1:], after[:, 1:]) / (
            np.linalg.norm(before[:, 1:], axis=1) * np.linalg.norm(after[:, 1:], axis=1))
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))) == pytest.approx(np.full(cos.size, abs(angle)), abs=1e-6), s
        assert np.allclose(before[:, 0], after[:, 0], rtol=0, atol=1e-12), s
    turned = P.in_turned_phone(rec.gyr.values, (1.0, 0.0, 0.0), np.radians(angle))
    assert np.allclose(a.gyr.values, turned)


def test_each_walk_has_its_own_draw():
    rec = _recording()
    other = Recording("walk_b.txt", "ipin", acc=rec.acc, gyr=rec.gyr, mag=rec.mag, pressure=rec.pressure)
    assert not np.array_equal(perturbed(rec, "gyro_bias").gyr.values, perturbed(other, "gyro_bias").gyr.values)
    assert not np.array_equal(perturbed(rec, "gyro_bias", seed=1).gyr.values, perturbed(rec, "gyro_bias").gyr.values)


def test_resampled_recording_shares_one_clock_for_acc_and_gyro():
    a = perturbed(_recording(), "rate60")
    assert np.array_equal(a.acc.t, a.gyr.t) and a.acc.rate_hz == pytest.approx(60.0)


def test_names_from():
    assert names_from("all") == list(PERTURBATIONS)
    assert names_from("rate50, gaps") == ["rate50", "gaps"]
    with pytest.raises(ValueError, match="unknown bogus"):
        names_from("rate50,bogus")


def test_verdict_follows_the_issues_criteria():
    base = {"a": 3.0, "b": 5.0}
    ok = verdict(4.0, base, 4.9, {"a": 7.9, "b": 5.0})  # +22.5 %, a at 7.9 <= 2 x 3 + 2
    assert ok["passes"] and ok["worst_walk"] == "a" and not ok["broken"]
    too_much = verdict(4.0, base, 5.1, {"a": 3.0, "b": 5.0})
    assert not too_much["passes"] and too_much["pooled_change"] == pytest.approx(0.275)
    broken = verdict(4.0, base, 4.0, {"a": 8.1, "b": 5.0})
    assert not broken["passes"] and [b["walk"] for b in broken["broken"]] == ["a"]


# --------------------------------------------------------------------------------------------
# The barometer
# --------------------------------------------------------------------------------------------
def test_a_ventilation_fan_raises_the_pressure_for_the_rest_of_the_walk():
    t = np.arange(0.0, 200.0, 0.1)
    for seed in range(20):
        start, end, dp = P.fan_started(0.0, 200.0, seed)
        assert 40.0 <= start <= 120.0 and end == np.inf and 0.20 <= dp <= 0.50  # hPa: 20-50 Pa
        p = P.pressure_offsets(t, np.full(t.size, 1000.0), [(start, end, dp)])[:, 0]
        assert np.all(p[t <= start] == 1000.0) and np.allclose(p[t >= start + 2.0], 1000.0 + dp)
        assert np.all(np.diff(p) >= 0)  # it rises over the ramp, never back


def test_door_pulses_come_and_go_within_their_bounds():
    t = np.arange(0.0, 600.0, 0.1)
    pulses = P.door_pulses(0.0, 600.0, seed=3)
    assert 4 <= len(pulses) <= 20  # about one a minute
    for a, b, dp in pulses:
        assert 0.0 < b - a <= 20.0 and 0.10 <= abs(dp) <= 0.40
    p = P.pressure_offsets(t, np.full(t.size, 1000.0), pulses)[:, 0]
    quiet = np.ones(t.size, bool)
    for a, b, _ in pulses:
        quiet &= (t < a) | (t > b)
    assert np.all(p[quiet] == 1000.0) and np.abs(p - 1000.0).max() <= 0.40 + 1e-12


def test_drift_and_a_cheap_barometer():
    t = np.arange(0.0, 240.0, 0.1)
    p = P.pressure_drift(t, np.full(t.size, 1000.0), seed=5)[:, 0]
    total = p[-1] - p[0]
    assert 0.15 <= abs(total) <= 0.3 and np.allclose(np.diff(p), total / (t.size - 1))
    tc, pc = P.cheap_barometer(t, np.full((t.size, 1), 1000.0), seed=5)
    assert np.median(np.diff(tc)) == pytest.approx(1.0) and np.std(pc - 1000.0) == pytest.approx(0.05, rel=0.3)

"""Step detectors (pdr.steps): synthetic gait whose steps are known, plus Oxford walks when present."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from pdr import quaternion as quat
from pdr.steps import (
    DETECTORS,
    GRAVITY,
    NormDetector,
    PeakDetector,
    VerticalPairDetector,
    ZeroCrossingDetector,
    estimate_rate,
    make_detector,
    norm_minus_gravity,
    vertical_linear_acceleration,
)


def gait(amplitudes, freq=2.0, rate=100.0, lead=3.0, tail=3.0, noise=0.05, jitter=0.1, seed=0,
         shape2=0.3, pauses=None):
    """A gravity-free vertical signal with one bounce per step, and the true step peaks.

    Step k is one period of ``A_k (sin φ + shape2 sin 2φ)`` (a bounce with a harmonic) at
    cadence ``freq``; still ``lead`` s before and ``tail`` s after. ``pauses`` maps a step
    index to seconds of stillness inserted before it. Timestamps jitter by ``jitter`` of
    the sample interval. Returns ``t, a, peak_times``.
    """
    rng = np.random.default_rng(seed)
    period = 1.0 / freq
    starts, t0 = [], lead
    for k in range(len(amplitudes)):
        t0 += (pauses or {}).get(k, 0.0)
        starts.append(t0)
        t0 += period
    end = t0 + tail
    n = int(end * rate)
    t = np.arange(n) / rate + rng.uniform(-jitter, jitter, n) / rate
    a = rng.normal(0.0, noise, n)
    peaks = []
    for s, amp in zip(starts, amplitudes):
        m = (t >= s) & (t < s + period)
        phi = 2 * np.pi * (t[m] - s) / period
        a[m] += amp * (np.sin(phi) + shape2 * np.sin(2 * phi))
        peaks.append(s + 0.2 * period)
    return t, a, np.array(peaks)


def count(det, t, a):
    return len(det.detect(t, a))


# -- the signals -----------------------------------------------------------------------------
def test_estimate_rate_ignores_jitter_and_gaps():
    rng = np.random.default_rng(1)
    dt = np.full(2000, 0.01) + rng.uniform(-0.004, 0.004, 2000)
    dt[::97] = 0.2  # dropped samples
    t = np.concatenate([[0.0], np.cumsum(dt)])
    assert estimate_rate(t) == pytest.approx(100.0, rel=0.01)
    with pytest.raises(ValueError):
        estimate_rate([1.0, 1.0])


def test_vertical_linear_acceleration_undoes_the_rotation():
    rng = np.random.default_rng(2)
    q = quat.normalize(rng.normal(size=(50, 4)))
    lin = rng.normal(size=(50, 3))
    body = quat.rotate_inverse(q, lin + np.array([0.0, 0.0, GRAVITY]))
    np.testing.assert_allclose(vertical_linear_acceleration(q, body), lin[:, 2], atol=1e-9)
    assert norm_minus_gravity(np.array([[0.0, 0.0, GRAVITY]]))[0] == pytest.approx(0.0)


# -- every detector: N steps in, N steps out; any batching gives the same steps ---------------
@pytest.mark.parametrize("name", list(DETECTORS))
@pytest.mark.parametrize("rate", [50.0, 100.0, 400.0])
def test_counts_synthetic_gait(name, rate):
    t, a, peaks = gait([3.0] * 40, freq=1.8, rate=rate)
    steps = make_detector(name).detect(t, a)
    assert len(steps) == 40
    times = np.array([s.t for s in steps])
    assert np.all(np.diff(times) > 0.33)
    # each step is recognised after its bounce's peak and before the next bounce ends
    assert np.all(times >= peaks - 0.05) and np.all(times <= peaks + 2 / 1.8)


@pytest.mark.bitexact
@pytest.mark.parametrize("name", list(DETECTORS))
def test_streaming_in_batches_equals_one_batch(name):
    t, a, _ = gait([2.5, 3.5] * 15, freq=2.0, rate=100.0, seed=3)
    whole = make_detector(name).detect(t, a)
    assert len(whole) == 30
    for size in (1, 7, 100):
        det = make_detector(name)
        got = []
        for i in range(0, len(t), size):
            got += det.update(t[i : i + size], a[i : i + size])
        got += det.finish()
        assert got == whole, f"batches of {size}"


def test_step_statistics_cover_the_step():
    t, a, _ = gait([3.0] * 20, freq=2.0, shape2=0.0, noise=0.0)
    steps = NormDetector().detect(t, a)
    mid = steps[5:-5]
    for s in mid:
        assert s.duration == pytest.approx(0.5, abs=0.02)
        assert s.a_min < 0 < s.a_max
        assert 1.5 < s.a_max - s.a_min < 7.0
        assert 0 < s.a_mean_abs <= max(s.a_max, -s.a_min)
    assert steps[0].duration == pytest.approx(NormDetector().settings.max_step_s)


def test_zero_phase_is_offline_only_and_has_no_delay():
    t, a, peaks = gait([3.0] * 30, freq=2.0, noise=0.0)
    causal = np.array([s.t for s in PeakDetector().detect(t, a)])
    offline = np.array([s.t for s in PeakDetector().detect(t, a, zero_phase=True)])
    assert len(causal) == len(offline) == 30
    assert np.abs(offline - peaks).mean() < 0.05 and np.abs(causal - peaks).mean() > 0.2
    det = PeakDetector()
    det.update(t[:10], a[:10])
    with pytest.raises(RuntimeError):
        det.detect(t, a)


def test_make_detector_and_settings():
    det = make_detector("peak", {"threshold": "1.5"})
    assert isinstance(det, PeakDetector) and det.settings.threshold == 1.5
    with pytest.raises(ValueError, match="unknown step detector"):
        make_detector("nope")
    with pytest.raises(ValueError, match="unknown parameter"):
        make_detector("norm", {"thresh": 1})


def test_a_given_rate_skips_the_estimate_and_bad_samples_are_dropped():
    t, a, _ = gait([3.0] * 12, freq=2.0)
    det = NormDetector(NormDetector.Settings(rate_hz=100.0))
    assert det.rate_hz == 100.0
    a = a.copy()
    a[500] = np.nan
    steps = det.update(t, a) + det.finish()
    assert len(steps) == 12


def test_short_stream_is_processed_at_finish():
    t, a, _ = gait([3.0] * 6, freq=2.0, lead=0.2, tail=0.3)
    det = NormDetector(NormDetector.Settings(rate_window_s=60.0))
    assert det.update(t, a) == []
    assert len(det.finish()) == 6


# -- the smartphone thesis's max/min pairs (Ryšánek §3.5.2) -------------------------------------
def test_vertical_pair_threshold():
    # swing a_max - a_min = 2 A (1 + ...) around the 1.8 m/s² limit
    assert count(VerticalPairDetector(), *gait([0.7] * 20, shape2=0.0)[:2]) == 0
    assert count(VerticalPairDetector(), *gait([1.3] * 20, shape2=0.0)[:2]) == 20


def test_vertical_pair_maximum_time():
    # max -> min takes half a period: 0.83 s at 0.6 Hz (> 714 ms), 0.62 s at 0.8 Hz
    assert count(VerticalPairDetector(), *gait([3.0] * 12, freq=0.6, shape2=0.0)[:2]) == 0
    assert count(VerticalPairDetector(), *gait([3.0] * 12, freq=0.8, shape2=0.0)[:2]) == 12


def test_vertical_pair_minimum_time():
    wide = VerticalPairDetector.Settings(high_hz=12.0)  # let fast bounces through the filter
    # half a period: 83 ms at 6 Hz (< 100 ms), 125 ms at 4 Hz
    assert count(VerticalPairDetector(wide), *gait([3.0] * 30, freq=6.0, shape2=0.0, rate=400)[:2]) == 0
    assert count(VerticalPairDetector(wide), *gait([3.0] * 30, freq=4.0, shape2=0.0, rate=400)[:2]) == 30


def test_vertical_rejects_an_odd_band_pass_order():
    with pytest.raises(ValueError, match="even"):
        VerticalPairDetector(VerticalPairDetector.Settings(order=5)).detect(*gait([3.0] * 5)[:2])


# -- the handheld thesis's peaks and zero crossings (Tupý §2.2) ---------------------------------
def test_peak_threshold():
    assert count(PeakDetector(), *gait([1.5] * 20)[:2]) == 0  # peaks about 1.8 m/s² < 2
    assert count(PeakDetector(), *gait([2.6] * 20)[:2]) == 20


def test_peak_minimum_interval():
    wide = PeakDetector.Settings(cutoff_hz=10.0)
    # 4 Hz: peaks 0.25 s apart, every other one is too soon after the last step; 2.5 Hz: 0.4 s
    assert count(PeakDetector(wide), *gait([3.0] * 40, freq=4.0, shape2=0.0, rate=200)[:2]) == 20
    assert count(PeakDetector(wide), *gait([3.0] * 40, freq=2.5, shape2=0.0, rate=200)[:2]) == 40


def test_peak_step_span_is_bounded():
    t, a, _ = gait([3.0] * 10, freq=2.0, pauses={5: 3.0})
    steps = PeakDetector().detect(t, a)
    assert len(steps) == 10
    assert steps[5].duration == pytest.approx(PeakDetector().settings.max_step_s)
    assert steps[6].duration == pytest.approx(0.5, abs=0.02)


def test_zero_crossing_threshold():
    assert count(ZeroCrossingDetector(), *gait([1.2] * 20, shape2=0.0)[:2]) == 0
    assert count(ZeroCrossingDetector(), *gait([2.6] * 20, shape2=0.0)[:2]) == 20


def test_zero_crossing_minimum_interval():
    wide = ZeroCrossingDetector.Settings(cutoff_hz=10.0)
    # crossings 0.25 s apart at 4 Hz: a crossing sooner than 0.33 s after the start is inside the step
    steps = ZeroCrossingDetector(wide).detect(*gait([3.0] * 40, freq=4.0, shape2=0.0, rate=200)[:2])
    assert abs(len(steps) - 20) <= 1
    assert np.median([s.duration for s in steps]) == pytest.approx(0.5, abs=0.01)
    # at 2.5 Hz (0.4 s) every crossing starts a step
    assert count(ZeroCrossingDetector(wide), *gait([3.0] * 40, freq=2.5, shape2=0.0, rate=200)[:2]) == 40


def test_zero_crossing_timeout():
    # a 0.8 Hz bounce: crossings 1.25 s apart, each step is closed by the 1 s timeout
    steps = ZeroCrossingDetector().detect(*gait([3.0] * 10, freq=0.8, shape2=0.0)[:2])
    assert len(steps) == 10
    assert all(s.duration == pytest.approx(1.0) for s in steps)
    longer = ZeroCrossingDetector(ZeroCrossingDetector.Settings(max_step_s=1.5))
    assert np.median([s.duration for s in longer.detect(*gait([3.0] * 10, freq=0.8, shape2=0.0)[:2])]) == pytest.approx(1.25, abs=0.02)


# -- the orientation-free detector --------------------------------------------------------------
def test_norm_floor():
    assert count(NormDetector(), *gait([0.3] * 30)[:2]) == 0
    assert count(NormDetector(), *gait([0.8] * 30)[:2]) == 30


def test_norm_relative_threshold_keeps_the_weaker_leg_and_drops_ripples():
    # a phone on one thigh: strong and weak steps alternate, both count
    assert count(NormDetector(), *gait([4.0, 2.0] * 15, noise=0.0)[:2]) == 30
    # a bump a fifth of the steps' size between them (above the floor) is not a step
    assert count(NormDetector(), *gait([4.0, 0.9] * 15, freq=2.4, noise=0.0)[:2]) == 15
    assert count(NormDetector(NormDetector.Settings(relative=0.0)), *gait([4.0, 0.9] * 15, freq=2.4, noise=0.0)[:2]) == 30
    # nor is the band-pass's ring-out after an abrupt stop (a bump a third of a step)
    every = NormDetector.Settings(min_bout_steps=1)
    assert count(NormDetector(every), *gait([3.0] * 10, freq=2.0)[:2]) == 10
    assert count(NormDetector(dataclasses.replace(every, relative=0.0)), *gait([3.0] * 10, freq=2.0)[:2]) == 11


def test_norm_reference_fades_after_a_pause():
    # a vigorous walk, 10 s still, then a walk a fifth as strong: it is counted again
    steps = NormDetector().detect(*gait([5.0] * 20 + [1.0] * 20, pauses={20: 10.0})[:2])
    assert len(steps) == 40
    # without the pause the gentle walk is below 0.35 x the vigorous steps until the fade
    steps = NormDetector().detect(*gait([5.0] * 20 + [1.0] * 20)[:2])
    assert 20 < len(steps) < 40


def test_norm_minimum_interval():
    # 3.5 Hz: 0.29 s between bounces, every other one too soon; 2.8 Hz: 0.36 s, all steps
    assert count(NormDetector(), *gait([3.0] * 40, freq=3.5, rate=200, shape2=0.0)[:2]) == 20
    assert count(NormDetector(), *gait([3.0] * 40, freq=2.8, rate=200, shape2=0.0)[:2]) == 40


def test_norm_bouts():
    groups_of = lambda n, k: {i: 2.0 for i in range(n, n * k, n)}  # noqa: E731
    # three steps, a 2 s pause, three steps, ...: never a bout of 4
    assert count(NormDetector(), *gait([3.0] * 15, pauses=groups_of(3, 5))[:2]) == 0
    assert count(NormDetector(), *gait([3.0] * 15, pauses=groups_of(5, 3))[:2]) == 15
    # steps more than 1 s apart (0.9 Hz) are not a walking bout; 1.2 Hz is
    assert count(NormDetector(), *gait([3.0] * 12, freq=0.9)[:2]) == 0
    assert count(NormDetector(), *gait([3.0] * 12, freq=1.2)[:2]) == 12
    # every candidate counts when bouts are switched off
    assert count(NormDetector(NormDetector.Settings(min_bout_steps=1)), *gait([3.0] * 3)[:2]) == 3


def test_norm_releases_a_bout_with_the_steps_own_times():
    t, a, _ = gait([3.0] * 10, freq=2.0)
    det, released = NormDetector(), []
    for i in range(0, len(t), 5):
        new = det.update(t[i : i + 5], a[i : i + 5])
        if new:
            released.append(new)
    assert [len(r) for r in released][:1] == [4]  # nothing until the fourth step, then all four
    assert sum(released, []) + det.finish() == NormDetector().detect(t, a)


def test_norm_is_orientation_free():
    # the same bounce seen by a phone in three attitudes gives the same steps
    t, lin, _ = gait([2.5] * 30, freq=1.9, seed=4)
    up = np.column_stack([np.zeros_like(lin), np.zeros_like(lin), GRAVITY + lin])
    counts = set()
    for rv in ([0, 0, 0], [1.2, 0, 0], [0.3, -2.0, 0.7]):
        body = quat.rotate_inverse(quat.from_rotation_vector(np.array(rv, float)), up)
        counts.add(count(NormDetector(), t, norm_minus_gravity(body)))
    assert counts == {30}


# -- real recordings ---------------------------------------------------------------------------
OXFORD_WALKS = [
    "oxford-steps/optimisation/Pixel_Jamie_Hard_InHand_1",
    "oxford-steps/optimisation/Samsung_Carmelo_Hard_BackPocket_1",
    "oxford-steps/optimisation/Samsung_Dario_Hard_Purse_2",
    "oxford-steps/optimisation/Samsung_Dario_Hard_NeckPouch_1",
    "oxford-steps/validation/user2_hand_1506421987098.csv.gz",
]


@pytest.mark.recording
@pytest.mark.parametrize("walk", OXFORD_WALKS)
def test_oxford_walk_within_5_percent(shared_data, walk):
    from pdr.io import load
    from pdr.steps.scoring import count_steps

    rec = load(shared_data(walk))
    c = count_steps(rec, "norm")
    assert abs(c.error_pct) <= 5.0, f"{walk}: {c.detected_steps} detected, {c.true_steps} true"


@pytest.mark.recording
def test_oxford_walk_streamed_in_live_batches(shared_data):
    from pdr.io import load

    rec = load(shared_data(OXFORD_WALKS[1]))
    t, a = rec.acc.t, norm_minus_gravity(rec.acc.values)
    whole = NormDetector().detect(t, a)
    det, got = NormDetector(), []
    for i in range(0, len(t), 37):
        got += det.update(t[i : i + 37], a[i : i + 37])
    assert got + det.finish() == whole


@pytest.mark.recording
def test_eval_steps_command_json(shared_data):
    from typer.testing import CliRunner

    from client.cli import app

    walk = shared_data(OXFORD_WALKS[0])
    result = CliRunner().invoke(app, ["eval", "steps", str(walk), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    (row,) = report["files"]
    assert set(row) == {"file", "true_steps", "detected_steps", "error_pct"}
    assert row["true_steps"] == 292
    assert report["mean_abs_error_pct"] == pytest.approx(abs(row["error_pct"]))


# -- the command, on small files written here ----------------------------------------------------
def _oxford_files(tmp_path):
    """A validation-layout file with a true count (12 steps) and an optimisation-layout one without."""
    t, a, _ = gait([3.0] * 12, freq=2.0, seed=5)
    ns = np.round((t - t[0] + 1000.0) * 1e9).astype(np.int64)
    truth = np.searchsorted(np.arange(12) * 0.5 + 3.1, t - t[0])  # a running count, 0 -> 12
    validation = tmp_path / "user9_hand_1500000000000.csv"
    validation.write_text("".join(f"{n},0.0,0.0,{GRAVITY + x:.5f},0,{c},0\n" for n, x, c in zip(ns, a, truth)))
    walk = tmp_path / "Phone_User_Hard_InHand_1"
    walk.mkdir()
    (walk / "accelerometer.csv").write_text("".join(f"{n},3,{GRAVITY + x:.5f},0.0,0.0\n" for n, x in zip(ns, a)))
    return validation, walk


def test_eval_steps_command_reports_files_without_a_count(tmp_path):
    from typer.testing import CliRunner

    from client.cli import app

    validation, walk = _oxford_files(tmp_path)
    result = CliRunner().invoke(app, ["eval", "steps", str(validation), str(walk), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    counted, unknown = report["files"]
    assert counted == {"file": str(validation), "true_steps": 12, "detected_steps": 12, "error_pct": 0.0}
    assert unknown["true_steps"] is None and unknown["error_pct"] is None and unknown["detected_steps"] == 12
    assert report["mean_abs_error_pct"] == 0.0
    table = CliRunner().invoke(app, ["eval", "steps", str(validation), str(walk), "-d", "vertical"])
    assert table.exit_code == 0 and "user9_hand" in table.stdout
    bad = CliRunner().invoke(app, ["eval", "steps", str(walk), "--detector", "stride"])
    assert bad.exit_code == 2 and "Traceback" not in bad.output


@pytest.mark.bitexact
def test_compiled_sos_filter_matches_scipy_and_any_chunking():
    from scipy import signal

    from pdr.steps.base import bandpass_sos
    from pdr.steps.sosfilter import sos_filter

    rng = np.random.default_rng(5)
    x = rng.normal(size=3000)
    sos = np.ascontiguousarray(bandpass_sos(4, 0.5, 3.0, 100.0))
    zi0 = signal.sosfilt_zi(sos) * x[0]
    ref, _ = signal.sosfilt(sos, x, zi=zi0)
    whole = sos_filter(sos, x, zi0.copy())
    assert np.allclose(whole, ref, rtol=0, atol=1e-12)
    zi, parts, i = zi0.copy(), [], 0
    for n in (1, 10, 7, 500, 3, 1000, 10_000):
        parts.append(sos_filter(sos, x[i:i + n], zi))
        i += n
    assert np.array_equal(np.concatenate(parts), whole)  # bit for bit, however cut

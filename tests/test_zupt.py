"""The boot-mounted INS (pdr.zupt): detectors, filter, strides, motion states, streaming.

Synthetic boots (:mod:`pdr.zupt.synthetic`) carry their truth; one test runs a real PyShoe
recording when ../shared/data is present.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pdr.events import MotionEvent, MotionState, StepEvent
from pdr.floors import FloorElevations
from pdr.pipeline import ImuFrame, frames_of, run_pipeline
from pdr.zupt import DetectorSettings, InsSettings, ZeroVelocityDetector, ZuptIns, ZuptSettings, initial_attitude
from pdr.zupt.motion_model import ZuptMotionModel
from pdr.zupt.settings import GaitSettings, StrideSettings
from pdr.zupt.synthetic import foot_walk, square_strides
from pdr import quaternion as quat

NOISE = dict(acc_noise=0.02, gyr_noise=math.radians(0.5))  # the 3DM-GX3's white noise per sample at 200 Hz


def run_ins(w, settings=None, batch=None):
    ins = ZuptIns(settings)
    outs = []
    n = len(w.t)
    for i in range(0, n, batch or n):
        outs.append(ins.update(w.t[i:i + (batch or n)], w.acc[i:i + (batch or n)], w.gyr[i:i + (batch or n)]))
    outs.append(ins.finish())
    return ins, outs


def cat(outs, name):
    return np.concatenate([getattr(o, name) for o in outs])


def events_of(w, model=None, per_frame=10):
    model = model or ZuptMotionModel()
    return model, run_pipeline(model, frames_of(w.t, w.acc, w.gyr, per_frame=per_frame))


def steps(events):
    return [e for e in events if isinstance(e, StepEvent)]


def motions(events):
    return [e for e in events if isinstance(e, MotionEvent)]


# ---------------------------------------------------------------------------- the walk


@pytest.fixture(scope="module")
def square():
    """A closed square, 6 strides of 1.2 m per side, with sensor noise."""
    return foot_walk(square_strides(6, 1.2), seed=1, **NOISE)


def test_initial_attitude_levels_the_resting_boot():
    for q_true in (quat.from_yaw(0.0), quat.multiply(quat.from_yaw(0.0), np.array([0.0, 1.0, 0.0, 0.0])),
                   quat.from_rotation_vector(np.array([0.3, -0.5, 0.0]))):
        f = quat.rotate_inverse(q_true, np.array([0.0, 0.0, 9.81]))  # specific force at rest, body frame
        q = initial_attitude(f)
        np.testing.assert_allclose(quat.rotate(q, f), [0.0, 0.0, 9.81], atol=1e-9)
        up_body = quat.rotate_inverse(q, np.array([0.0, 0.0, 1.0]))
        np.testing.assert_allclose(up_body, f / np.linalg.norm(f), atol=1e-12)


def test_square_walk_stances_follow_the_truth_and_close(square):
    w = square
    ins, outs = run_ins(w)
    stances = np.concatenate([o.stances.position for o in outs])
    assert len(stances) == len(w.stance_positions)  # one per rest: the start and each stride
    # yaw 0 is the boot's x axis at the start, which points east in the synthetic walk: same frame
    err = np.linalg.norm(stances[:, :2] - w.stance_positions[:, :2], axis=1)
    distance = 24 * 1.2
    assert err.max() < 0.01 * distance, err.max()
    assert np.linalg.norm(stances[-1, :2] - stances[0, :2]) < 0.005 * distance  # the square closes
    stationary = cat(outs, "stationary")
    assert (stationary == w.stance).mean() > 0.95
    assert np.all(np.isfinite(cat(outs, "position")))  # the walk starts still: every sample has a position


def test_square_walk_stride_events(square):
    model, events = events_of(square)
    st = steps(events)
    assert len(st) == 24 and [e.index for e in st] == list(range(1, 25))
    lengths = np.array([e.length for e in st])
    np.testing.assert_allclose(lengths, 1.2, atol=0.012)
    turns = np.degrees([e.heading_change for e in st])
    corners = np.zeros(24, bool)
    corners[[6, 12, 18]] = True
    np.testing.assert_allclose(turns[corners], 90.0, atol=1.0)
    np.testing.assert_allclose(turns[~corners], 0.0, atol=1.0)
    assert all(abs(e.dz) < 0.02 and not e.on_stairs for e in st)
    for e in st:  # sigmas finite and positive; no compass: heading unknown, compass fields empty
        assert 0 < e.length_sigma < 0.1 and 0 < e.heading_change_sigma < 0.1 and 0 < e.dz_sigma < 0.1
        assert e.heading_sigma >= math.pi and math.isnan(e.mag_heading) and e.mag_heading_sigma == math.inf
    # a dead-reckoned chain of the events reproduces the INS's stances
    xy = np.cumsum([[e.length * math.cos(e.heading), e.length * math.sin(e.heading)] for e in st], axis=0)
    np.testing.assert_allclose(xy[-1], 0.0, atol=0.15)
    assert model.steps == 24 and model.state is MotionState.WALKING


def test_initial_yaw_turns_the_ins_frame():
    w = foot_walk([(1.0, 0.0, 0.0)] * 3, seed=2)
    model, events = events_of(w, ZuptMotionModel(initial_yaw=math.radians(30.0)))
    st = steps(events)
    np.testing.assert_allclose([e.heading for e in st], math.radians(30.0), atol=math.radians(1.0))
    assert all(e.heading_sigma < 0.01 for e in st)  # aligned: the filter's own yaw sigma


def test_no_still_window_no_start_and_no_position():
    rng = np.random.default_rng(0)
    t = np.arange(400) / 200.0
    acc = rng.normal(0.0, 8.0, (400, 3)) + [0.0, 0.0, 9.8]
    gyr = rng.normal(0.0, 3.0, (400, 3))
    ins = ZuptIns()
    out = ins.update(t, acc, gyr)
    out2 = ins.finish()
    assert not ins.started
    assert len(out) + len(out2) == 400 and np.isnan(cat([out, out2], "position")).all()


# ---------------------------------------------------------------------------- biases


def test_bias_estimates_converge_on_a_turning_walk():
    rng = np.random.default_rng(3)
    strides = [(1.2, turn, 0.0) for turn in rng.normal(0.0, 0.6, 60)]
    bg = np.array([0.01, -0.008, 0.006])  # rad/s, turn-on biases of a MEMS gyro
    ba = np.array([0.05, -0.04, 0.08])  # m/s²
    w = foot_walk(strides, gyr_bias=bg, acc_bias=ba, seed=2, still_start_s=5.0, **NOISE)
    s = ZuptSettings(ins=InsSettings(init_gyro_bias_sigma=0.02, init_acc_bias_sigma=0.1))
    ins = ZuptIns(s)  # starts from zero biases: the initial errors are the biases themselves
    for i in range(0, len(w.t), 400):
        ins.update(w.t[i:i + 400], w.acc[i:i + 400], w.gyr[i:i + 400])
    g_err, a_err = np.abs(ins.gyro_bias - bg), np.abs(ins.acc_bias - ba)
    # within 10 % of the bias on the level axes, 25 % on the one the boot's pitching reveals least
    assert np.all(g_err < np.array([0.1, 0.1, 0.25]) * np.abs(bg)), (g_err, bg)
    assert np.all(a_err < 0.1 * np.abs(ba)), (a_err, ba)
    # the biases matter: without estimating them the same walk drifts further
    off = ZuptSettings(ins=InsSettings(init_gyro_bias_sigma=1e-9, init_acc_bias_sigma=1e-9))
    end_with = run_ins(w, s)[0].position
    end_without = run_ins(w, off)[0].position
    truth = w.stance_positions[-1]
    assert np.linalg.norm(end_with[:2] - truth[:2]) < 0.5 * np.linalg.norm(end_without[:2] - truth[:2])


def test_zaru_learns_the_vertical_gyro_bias_while_standing():
    bg = np.array([0.0, 0.0, 0.01])
    w = foot_walk([(1.0, 0.0, 0.0)], gyr_bias=bg, still_start_s=20.0, still_end_s=20.0, seed=4, **NOISE)
    base = InsSettings(init_gyro_bias_sigma=0.02)
    with_zaru = run_ins(w, ZuptSettings(ins=dataclasses.replace(base, zaru_max_rate=0.05)))[0]
    without = run_ins(w, ZuptSettings(ins=base))[0]
    err_with, err_without = abs(with_zaru.gyro_bias[2] - bg[2]), abs(without.gyro_bias[2] - bg[2])
    assert err_with < 1e-3 and err_with < 0.5 * err_without  # at rest ZUPT alone does not see the yaw rate


# ---------------------------------------------------------------------------- detectors


def _decide(settings, t, acc, gyr):
    det = ZeroVelocityDetector(settings)
    d = det.update(t, acc, gyr)
    d2 = det.finish()
    return np.concatenate([d.stationary, d2.stationary]), np.concatenate([d.statistic, d2.statistic]), \
        np.concatenate([d.threshold, d2.threshold])


def _rest(n=41, rate=200.0, rate_norm=0.0, acc_dev=0.0, g=9.80665):
    """A boot at rest: specific force g along z (plus a ± deviation along x, alternating),
    a constant angular rate of norm ``rate_norm``."""
    t = np.arange(n) / rate
    acc = np.tile([0.0, 0.0, g], (n, 1))
    acc[:, 0] += acc_dev * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    gyr = np.tile([rate_norm, 0.0, 0.0], (n, 1))
    return t, acc, gyr


@pytest.mark.parametrize("below", [True, False])
def test_ared_threshold(below):
    s = DetectorSettings(detector="ared", ared_threshold_rad_s=0.5)
    zv, stat, thr = _decide(s, *_rest(rate_norm=0.5 * (0.99 if below else 1.01)))
    np.testing.assert_allclose(stat, (0.5 * (0.99 if below else 1.01)) ** 2, rtol=1e-12)
    assert np.all(thr == 0.25) and np.all(zv == below)


@pytest.mark.parametrize("below", [True, False])
def test_mv_threshold(below):
    s = DetectorSettings(detector="mv", mv_threshold_m_s2=0.5)
    dev = 0.5 * (0.98 if below else 1.02)
    zv, stat, thr = _decide(s, *_rest(n=40, acc_dev=dev))
    # inner windows of 5 alternating samples: variance dev² (1 - 1/25)
    inner = stat[3:-3]
    np.testing.assert_allclose(inner, dev * dev * (1 - 1 / 25), rtol=1e-9)
    assert np.all(zv[3:-3] == (dev * dev * 0.96 < 0.25))


@pytest.mark.parametrize("below", [True, False])
def test_shoe_threshold(below):
    s = DetectorSettings(detector="shoe", shoe_threshold=1.0e4)
    rate = math.sqrt(1.0e4) * s.gyro_sigma * (0.99 if below else 1.01)  # T = |ω|²/σ_ω² with the force on gravity
    zv, stat, thr = _decide(s, *_rest(rate_norm=rate, g=s.gravity))
    np.testing.assert_allclose(stat, (rate / s.gyro_sigma) ** 2, rtol=1e-9)
    assert np.all(zv == below)


def test_shoe_statistic_counts_force_off_gravity():
    s = DetectorSettings(detector="shoe")
    t, acc, gyr = _rest(g=s.gravity + 0.5)  # 0.5 m/s² too much, along the window's own direction
    _, stat, _ = _decide(s, t, acc, gyr)
    np.testing.assert_allclose(stat, (0.5 / s.acc_sigma) ** 2, rtol=1e-9)


def test_adaptive_threshold_rises_with_impacts_and_follows_the_stance_floor():
    s = DetectorSettings(detector="adaptive")
    t, acc, gyr = _rest(n=400, g=s.gravity)
    gyr[200:, 0] = math.sqrt(3.0e4) * s.gyro_sigma  # after a second at rest, SHOE 3e4: above γ0 = 1e4
    zv, stat, thr = _decide(s, t, acc, gyr)
    assert zv[5:195].all()
    np.testing.assert_allclose(stat[210:390], 3.0e4, rtol=1e-9)
    np.testing.assert_allclose(thr[210:390], s.shoe_threshold)  # walking-grade: the base threshold
    assert not zv[210:390].any()
    # an impact of 5 g raises the threshold by (A/A0)^κ (capped at γ_max) for the intensity window
    acc2 = acc.copy()
    acc2[205] = [0.0, 0.0, 49.0]
    zv2, _, thr2 = _decide(s, t, acc2, gyr)
    expected = min(s.shoe_threshold * (49.0 / s.adaptive_reference_m_s2) ** s.adaptive_exponent, s.adaptive_max_threshold)
    assert expected > 3.0e4
    np.testing.assert_allclose(thr2[210:390], expected, rtol=1e-12)
    assert zv2[210:390].all()
    # a sprint whose stances never get quieter than SHOE 2e5: the floor of the previous bins, F,
    # keeps γ at c·F (up to the ceiling), so every stance still gets its update
    gyr3 = gyr.copy()
    gyr3[:, 0] = math.sqrt(2.0e5) * s.gyro_sigma
    zv3, _, thr3 = _decide(s, t, acc, gyr3)
    np.testing.assert_allclose(thr3[25:], min(s.adaptive_floor_factor * 2.0e5, s.adaptive_ceiling), rtol=1e-9)
    assert zv3[25:].all() and not zv3[:15].any()  # the first bin has no floor yet


def test_detector_rejects_bad_input_with_a_clear_error():
    det = ZeroVelocityDetector()
    t, acc, gyr = _rest(n=10)
    with pytest.raises(ValueError, match="increase"):
        det.update(t[::-1].copy(), acc, gyr)
    with pytest.raises(ValueError, match="non-finite"):
        bad = acc.copy()
        bad[3, 1] = np.nan
        ZeroVelocityDetector().update(t, bad, gyr)
    with pytest.raises(ValueError, match=r"expected \(10, 3\)"):
        ZeroVelocityDetector().update(t, acc[:, :2], gyr)
    det.update(t, acc, gyr)
    with pytest.raises(ValueError, match="increase"):
        det.update(t, acc, gyr)  # the same times again


@pytest.mark.parametrize("bad", [dict(detector="nope"), dict(window_s=0.0), dict(shoe_threshold=-1.0),
                                 dict(adaptive_max_threshold=1.0), dict(intensity_bin_s=5.0)])
def test_detector_settings_are_checked(bad):
    with pytest.raises(ValueError):
        DetectorSettings(**bad)


@pytest.mark.parametrize("cls, bad", [(InsSettings, dict(zupt_sigma=0.0)), (InsSettings, dict(gravity=-9.8)),
                                      (InsSettings, dict(acc_bias_walk=-1.0)), (StrideSettings, dict(settle_s=0.0)),
                                      (GaitSettings, dict(crawl_tilt=0.0))])
def test_other_settings_are_checked(cls, bad):
    with pytest.raises(ValueError):
        cls(**bad)


# ---------------------------------------------------------------------------- streaming


@pytest.mark.bitexact
@pytest.mark.parametrize("detector", ["adaptive", "shoe", "ared", "mv"])
def test_ins_gives_the_same_bits_in_any_batching(square, detector):
    s = ZuptSettings(detector=DetectorSettings(detector=detector))
    _, whole = run_ins(square, s)
    ref = {k: cat(whole, k) for k in ("t", "position", "stationary", "threshold")}
    ref_st = np.concatenate([o.stances.position for o in whole])
    for batch in (1, 3, 10, 64, 1000):
        _, parts = run_ins(square, s, batch=batch)
        for k, v in ref.items():
            assert np.array_equal(cat(parts, k), v, equal_nan=True), (batch, k)
        assert np.array_equal(np.concatenate([o.stances.position for o in parts]), ref_st), batch


@pytest.mark.bitexact
def test_motion_model_gives_the_same_events_in_any_batching(square):
    _, whole = events_of(square, per_frame=len(square.t))
    for per_frame in (1, 7, 10, 333):
        _, ev = events_of(square, per_frame=per_frame)
        assert ev == whole, per_frame


def test_frames_must_come_in_time_order(square):
    m = ZuptMotionModel()
    m.update(ImuFrame(square.t[:10], square.acc[:10], square.gyr[:10]))
    with pytest.raises(ValueError, match="not after"):
        m.update(ImuFrame(square.t[5:15], square.acc[5:15], square.gyr[5:15]))


# ---------------------------------------------------------------------------- motion states and floors


def test_running_is_told_from_walking():
    w = foot_walk([(1.5, 0.0, 0.0)] * 12, swing_s=0.45, stance_s=0.2, still_end_s=4.0, seed=5, **NOISE)
    _, ev = events_of(w)
    states = [e.state for e in motions(ev)]
    assert MotionState.RUNNING in states and states[-1] is MotionState.STILL
    assert sum(1 for e in steps(ev)) == 12


def test_crawling_is_told_by_the_boot_resting_on_its_toe():
    w = foot_walk([(0.4, 0.0, 0.0, 0.0)] + [(0.3, 0.0, 0.0, 1.3)] * 10, pitch_rad=0.2, seed=6, **NOISE)
    _, ev = events_of(w)
    assert MotionState.CRAWLING in [e.state for e in motions(ev)]


def test_stairs_come_out_as_height_and_change_the_floor_without_a_barometer():
    floors = FloorElevations.uniform(3.0, 0, 3)
    w = foot_walk([(0.6, 0.0, 0.34)] * 20, seed=7, **NOISE)  # two risers of 0.17 m per stride
    model, ev = events_of(w, ZuptMotionModel(floors=floors))
    st = steps(ev)
    np.testing.assert_allclose([e.dz for e in st], 0.34, atol=0.02)
    assert all(e.on_stairs for e in st)
    assert MotionState.STAIRS in [e.state for e in motions(ev)]
    assert model.floor == 2 and st[-1].floor == 2  # 6.8 m up with floors 3 m apart
    assert abs(model.height - 6.8) < 0.2
    model.anchor_floor(1)  # a checkpoint says floor 1: the INS height is re-referenced
    assert model.floor == 1 and abs(model.height - 3.0) < 1e-9


def test_with_a_barometer_the_floor_follows_the_pressure():
    floors = FloorElevations.uniform(3.0, 0, 3)
    w = foot_walk([(0.6, 0.0, 0.34)] * 20, seed=8, **NOISE)
    # pressure of a barometer that climbs only 3.4 m (half the INS): the floor follows it, dz stays the INS's
    z = 0.5 * np.interp(w.t, w.t, w.position[:, 2])
    p = 1013.25 * (1.0 - 2.25577e-5 * z) ** 5.25588
    model = ZuptMotionModel(floors=floors)
    events = []
    for i in range(0, len(w.t), 20):
        sl = slice(i, i + 20)
        events += model.update(ImuFrame(w.t[sl], w.acc[sl], w.gyr[sl], pressure_t=w.t[sl][::4], pressure=p[sl][::4]))
    events += model.finish()
    assert model.floor == 1
    np.testing.assert_allclose([e.dz for e in steps(events)], 0.34, atol=0.02)


def test_no_motion_after_thirty_still_seconds():
    w = foot_walk([(1.0, 0.0, 0.0)] * 4, still_end_s=40.0, seed=9, **NOISE)
    _, ev = events_of(w)
    m = motions(ev)
    assert [e.state for e in m][-2:] == [MotionState.STILL, MotionState.NO_MOTION]
    last_stride = steps(ev)[-1].t
    assert abs(m[-1].t - (m[-1].since + 30.0)) <= 0.5 + 1e-9
    assert last_stride - 1.0 < m[-1].since < last_stride + 1.0


# ---------------------------------------------------------------------------- a real recording


@pytest.mark.recording
def test_a_pyshoe_vicon_walk_is_tracked_within_a_decimetre(shared_data):
    from pdr.evaluation.zupt import score_recording
    from pdr.io.pyshoe import load_pyshoe

    rec = load_pyshoe(shared_data("pyshoe-vicon/2017-11-22-11-22-03_LLIO.mat"))
    score = score_recording(rec, per_frame=10)
    assert score.ours.ate_rmse_m < 0.1
    assert abs(score.strides - len(rec.meta["stride_index"])) <= 2

"""Factor-graph fusion (service/fusion) on synthetic walks whose truth is known. Real gtsam, no mocks."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pdr.events import StepEvent
from service.fusion import (
    CheckpointFix,
    FusedPose,
    FusionSettings,
    GnssFix,
    TrackFusion,
    UwbRange,
)
from service.fusion.bench import bench_fusion
from service.fusion.noise import step_covariance

DEG = math.pi / 180.0
STEP_DT = 0.5  # s between steps (2 steps/s)


def walk(headings, length=0.8, turn_bias=0.0, turn_sigma=0.01, mag=None, mag_sigma=5 * DEG, floors=None,
         start_heading=None, t0=0.0, index0=1):
    """StepEvents for true step headings ``headings`` (rad) and the true positions (n+1, 2) from (0, 0).

    The PDR's turn per step is the true turn plus ``turn_bias`` (a gyro drift); ``mag`` is the
    compass reading per step (None: disturbed everywhere, NaN).
    """
    h = np.asarray(headings, dtype=float)
    n = len(h)
    h_prev = np.r_[h[0] if start_heading is None else start_heading, h[:-1]]
    steps = length * np.c_[np.cos(h), np.sin(h)]
    truth = np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])
    mag = np.full(n, np.nan) if mag is None else np.asarray(mag, dtype=float)
    floors = np.zeros(n, dtype=int) if floors is None else np.asarray(floors)
    events = [
        StepEvent(t=t0 + (k + 1) * STEP_DT, index=index0 + k, length=length, length_sigma=0.03, heading=float(h[k]),
                  heading_sigma=0.1, heading_change=float(h[k] - h_prev[k] + turn_bias), heading_change_sigma=turn_sigma,
                  dz=0.0, dz_sigma=0.1, floor=int(floors[k]), on_stairs=False, mag_heading=float(mag[k]),
                  mag_heading_sigma=mag_sigma if math.isfinite(mag[k]) else math.inf)
        for k in range(n)
    ]
    return events, truth


def square(side_steps=25):
    return np.repeat([0.0, math.pi / 2, math.pi, -math.pi / 2], side_steps)


def no_mag(**kw) -> FusionSettings:
    return FusionSettings(use_mag_heading=False, **kw)


def err(pose: FusedPose, xy) -> float:
    return math.hypot(pose.x - xy[0], pose.y - xy[1])


def track_err(track, truth, rows) -> np.ndarray:
    return np.hypot(track["x"][rows] - truth[rows, 0], track["y"][rows] - truth[rows, 1])


# ------------------------------------------------------------------ steps


def test_exact_steps_reproduce_dead_reckoning():
    events, truth = walk(square())
    f = TrackFusion(no_mag())
    first = f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
    assert first.source == "pdr" and first.index == 0 and first.steps == 0
    poses = [f.add_step(ev) for ev in events]
    xy = np.array([[p.x, p.y] for p in poses])
    np.testing.assert_allclose(xy, truth[1:], atol=1e-6)
    assert poses[-1].steps == len(events) and poses[-1].index == events[-1].index
    assert all(p.source == "pdr" for p in poses)
    np.testing.assert_allclose(poses[30].heading, math.pi / 2, atol=1e-6)


def test_step_covariance_correlates_turn_and_across_track():
    cov = step_covariance(0.8, 0.05, 0.02, 0.05)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    # a turn error δθ moves the step sideways by L·δθ: the across/rotation correlation is near 1
    rho = cov[1, 2] / math.sqrt(cov[1, 1] * cov[2, 2])
    assert 0.2 < rho < 1.0


def test_published_covariance_is_in_enu():
    """Walking north with an uncertain start heading: the big uncertainty is across track = east.

    The step-length scale is off here (its ±12 % prior would make the along-track sigma large too).
    """
    events, _ = walk(np.full(40, math.pi / 2))
    f = TrackFusion(no_mag(length_scale_sigma=None))
    f.start(0.0, 0.0, 0.0, math.pi / 2, heading_sigma=10 * DEG, position_sigma=0.1)
    p = [f.add_step(ev) for ev in events][-1]
    assert p.cov.shape == (2, 2)
    assert p.cov[0, 0] > 10 * p.cov[1, 1]  # east (across) >> north (along)
    assert math.sqrt(p.cov[0, 0]) == pytest.approx(32 * 10 * DEG, rel=0.25)  # ≈ distance × heading sigma


def test_unknown_first_turn_uses_absolute_heading():
    """First step with heading_change_sigma = inf: the turn comes loosely from the PDR heading."""
    events, truth = walk(np.full(10, math.pi / 2), start_heading=0.0)
    e0 = events[0]
    events[0] = StepEvent(**{**e0.__dict__, "heading_change": math.nan, "heading_change_sigma": math.inf})
    f = TrackFusion(no_mag())
    f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
    poses = [f.add_step(ev) for ev in events]
    assert err(poses[-1], truth[-1]) < 0.05
    assert poses[0].heading_sigma > 0.5  # the first turn really is uncertain


# ------------------------------------------------------------------ checkpoints


def test_checkpoint_corrects_heading_bias_and_the_past():
    """Square walk, PDR rotated by +8° (a wrong start heading); a checkpoint at the second corner."""
    events, truth = walk(square())
    f = TrackFusion(no_mag())
    f.start(0.0, 0.0, 0.0, heading=8 * DEG, heading_sigma=15 * DEG, position_sigma=0.3)
    for ev in events[:50]:
        before = f.add_step(ev)
    corner1 = 25
    track_before = f.smoothed_track()
    err_corner1_before = track_err(track_before, truth, corner1)
    assert err(before, truth[50]) > 3.0  # the bias really hurts: 2·sin(4°)·28 m ≈ 3.9 m
    after = f.add_fix(CheckpointFix(t=events[49].t, x=truth[50, 0], y=truth[50, 1], sigma=0.3, name="corner 2"))
    assert after is not None and after.source == "fused"
    assert err(after, truth[50]) < 0.3
    track_after = f.smoothed_track()
    assert track_err(track_after, truth, corner1) < 0.3 * err_corner1_before  # the history moved toward the truth
    assert np.all(track_err(track_after, truth, np.arange(51)) <= track_err(track_before, truth, np.arange(51)) + 0.05)
    # heading corrected too: the rest of the square is walked right
    for ev in events[50:]:
        last = f.add_step(ev)
    assert err(last, truth[-1]) < 1.0
    assert abs(last.heading - (-math.pi / 2)) < 2 * DEG


# ------------------------------------------------------------------ step-length scale


def test_scaled_step_factor_jacobians_match_finite_differences():
    """The hand-written error and Jacobians of the scaled step against gtsam's Pose2 maths."""
    import gtsam

    from service.fusion.scaled_step import scaled_step_factor

    length, turn = 0.7, 0.3
    f = scaled_step_factor(1, 2, 3, length, turn, gtsam.noiseModel.Unit.Create(3))
    rng = np.random.default_rng(3)
    for _ in range(5):
        a = gtsam.Pose2(*rng.normal(0, 2, 2), rng.uniform(-math.pi, math.pi))
        b = a.compose(gtsam.Pose2(*rng.normal(0.7, 0.3, 2), rng.normal(0.3, 0.5)))
        scale = float(rng.uniform(0.8, 1.2))
        v = gtsam.Values()
        v.insert(1, a)
        v.insert(2, b)
        v.insert(3, scale)
        z = gtsam.Pose2(scale * length * math.cos(turn), scale * length * math.sin(turn), turn)
        np.testing.assert_allclose(f.unwhitenedError(v), gtsam.Pose2.Logmap(z.between(a.between(b))), atol=1e-12)
        jac, _ = f.linearize(v).jacobian()
        eps, cols = 1e-7, []
        for key, dim in ((1, 3), (2, 3), (3, 1)):
            for i in range(dim):
                v2 = gtsam.Values(v)
                if dim == 3:
                    v2.update(key, v.atPose2(key).retract(eps * np.eye(3)[i]))
                else:
                    v2.update(key, v.atDouble(key) + eps)
                cols.append((f.unwhitenedError(v2) - f.unwhitenedError(v)) / eps)
        np.testing.assert_allclose(jac, np.array(cols).T, atol=1e-5)


def test_graph_learns_a_step_length_bias_from_checkpoints():
    """The PDR's steps are 10 % long; checkpoints every 25 steps teach the graph the factor 1/1.1,
    and the live track between checkpoints stops accumulating the along-track error."""
    events, truth = walk(np.zeros(150))  # straight: only the length is wrong
    events = [dataclasses.replace(ev, length=ev.length * 1.1) for ev in events]

    def run(settings):
        f = TrackFusion(settings)
        f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.01, position_sigma=0.05)
        live_err = []
        for k, ev in enumerate(events):
            p = f.add_step(ev)
            if (k + 1) % 25 == 24:  # one step before the next checkpoint: the worst of the segment
                live_err.append(err(p, truth[k + 1]))
            if (k + 1) % 25 == 0:
                p = f.add_fix(CheckpointFix(t=ev.t, x=truth[k + 1, 0], y=truth[k + 1, 1], sigma=0.1))
        return p, live_err

    p, live_err = run(no_mag())
    _, no_scale_err = run(no_mag(length_scale_sigma=None))
    assert p.length_scale == pytest.approx(1 / 1.1, abs=0.02)
    assert no_scale_err[-1] > 1.2  # without the scale: ≈ 10 % of the 19 m since the fix, every segment
    assert live_err[-1] < 0.3 * no_scale_err[-1]
    assert live_err[-1] < live_err[0]  # the first segment is walked before anything is learned


def test_no_fix_keeps_the_scale_at_its_prior():
    events, truth = walk(square())
    f = TrackFusion(no_mag())
    f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
    poses = [f.add_step(ev) for ev in events]
    assert poses[-1].length_scale == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose([[p.x, p.y] for p in poses], truth[1:], atol=1e-6)
    assert math.isnan(TrackFusion(no_mag(length_scale_sigma=None)).start(0, 0, 0, 0, 0.1).length_scale)


@pytest.mark.parametrize("bias_deg", [20.0, 40.0])
def test_large_correction_converges_within_the_fix(bias_deg):
    """iSAM2 takes one Gauss-Newton step per update: a fix that rotates 60 m of track needs the extra iterations."""
    events, truth = walk(square(40))
    results = {}
    for extra in (0, FusionSettings().fix_extra_updates):
        f = TrackFusion(no_mag(fix_extra_updates=extra))
        f.start(0.0, 0.0, 0.0, bias_deg * DEG, heading_sigma=1.5 * bias_deg * DEG, position_sigma=0.3)
        for ev in events[:80]:
            f.add_step(ev)
        results[extra] = f.add_fix(CheckpointFix(t=events[79].t, x=truth[80, 0], y=truth[80, 1], sigma=0.3))
    assert err(results[0], truth[80]) > 1.0  # one iteration is not enough ...
    assert err(results[FusionSettings().fix_extra_updates], truth[80]) < 0.05  # ... the defaults converge


def test_checkpoint_between_steps_inflates_by_the_distance_walked():
    events, truth = walk(np.zeros(20))
    f = TrackFusion(no_mag())
    f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
    for ev in events:
        f.add_step(ev)
    # stamped a quarter of a step after pose 10: attaches to pose 10, sigma grows by 0.2 m
    f.add_fix(CheckpointFix(t=events[9].t + 0.25 * STEP_DT, x=truth[10, 0] + 0.2, y=truth[10, 1], sigma=0.1))
    ev = f.events[-1]
    assert ev.kind == "accepted" and ev.values["row"] == 10
    assert ev.values["slip_m"] == pytest.approx(0.25 * 0.8)


def test_the_graph_never_relabels_floors_the_motion_model_owns_them():
    """One owner of the floor: a checkpoint's floor anchors the motion model (the tracker's
    business); the graph keeps each step's floor, so a floor is never corrected twice."""
    events, _ = walk(np.zeros(30), floors=np.full(30, 1))
    f = TrackFusion(no_mag())
    f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05, floor=1)
    for ev in events[:20]:
        f.add_step(ev)
    pose = f.add_fix(CheckpointFix(t=events[9].t, x=8.0, y=0.0, floor=3))
    assert pose is not None and pose.floor == 1
    assert np.all(f.smoothed_track()["floor"] == 1)


# ------------------------------------------------------------------ UWB


def test_uwb_range_pulls_toward_the_circle():
    events, truth = walk(np.zeros(40))
    f = TrackFusion(no_mag())
    f.start(0.0, 0.0, 0.0, heading=10 * DEG, heading_sigma=15 * DEG, position_sigma=0.3)
    for ev in events:
        before = f.add_step(ev)
    anchor = np.array([32.0, -10.0])
    r = float(np.hypot(*(truth[-1] - anchor)))
    miss_before = abs(math.hypot(before.x - anchor[0], before.y - anchor[1]) - r)
    assert miss_before > 3.0
    after = f.add_fix(UwbRange(t=events[-1].t, anchor_x=anchor[0], anchor_y=anchor[1], range=r, sigma=0.2, anchor="A1"))
    miss_after = abs(math.hypot(after.x - anchor[0], after.y - anchor[1]) - r)
    assert miss_after < 0.5
    assert err(after, truth[-1]) < 0.5 * err(before, truth[-1])
    # a second range to the same anchor reuses its variable
    n_vars = f.window_variables
    f.add_fix(UwbRange(t=events[-2].t, anchor_x=anchor[0], anchor_y=anchor[1], range=float(np.hypot(*(truth[-2] - anchor))),
                       sigma=0.2, anchor="A1"))
    assert f.window_variables == n_vars


def test_uwb_gate_is_optional():
    events, truth = walk(np.zeros(20))
    gated = TrackFusion(no_mag(uwb_gate_probability=0.999))
    plain = TrackFusion(no_mag())
    bad = UwbRange(t=events[-1].t, anchor_x=16.0, anchor_y=5.0, range=35.0, sigma=0.2)  # true range 5 m
    for f in (gated, plain):
        f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
        for ev in events:
            f.add_step(ev)
    assert gated.add_fix(bad) is None and gated.rejected["uwb_gate"] == 1
    assert plain.add_fix(bad) is not None


# ------------------------------------------------------------------ GNSS


def test_gnss_outlier_rejected_consistent_fix_accepted():
    events, truth = walk(np.zeros(60))
    f = TrackFusion(no_mag(display_gain=1.0))  # the graph's own estimate is published
    f.start(0.0, 0.0, 0.0, heading=5 * DEG, heading_sigma=10 * DEG, position_sigma=1.0)
    for ev in events:
        live = f.add_step(ev)
    t = events[-1].t
    assert f.add_fix(GnssFix(t=t, x=truth[-1, 0] + 80.0, y=truth[-1, 1], accuracy=5.0)) is None
    assert f.rejected["gnss_gate"] == 1
    assert f.live is live  # a rejected fix changes nothing
    assert f.add_fix(GnssFix(t=t, x=truth[-1, 0], y=truth[-1, 1], accuracy=80.0)) is None
    assert f.rejected["gnss_accuracy"] == 1
    good = f.add_fix(GnssFix(t=t, x=truth[-1, 0] + 1.0, y=truth[-1, 1] - 1.0, accuracy=3.0))
    assert good is not None and good.source == "fused"
    assert err(good, truth[-1]) < err(live, truth[-1])
    assert [e.kind for e in f.events][-3:] == ["rejected", "rejected", "accepted"]


# ------------------------------------------------------------------ time


def test_late_fix_changes_the_past_not_published_poses():
    events, truth = walk(np.zeros(60))
    f = TrackFusion(no_mag())
    f.start(0.0, 0.0, 0.0, heading=8 * DEG, heading_sigma=15 * DEG, position_sigma=0.3)
    published = [f.add_step(ev) for ev in events]
    snapshot = [(p.t, p.x, p.y, p.heading, p.cov.copy(), p.floor, p.source) for p in published]
    past_before = f.smoothed_track()
    live = f.add_fix(CheckpointFix(t=events[29].t, x=truth[30, 0], y=truth[30, 1], sigma=0.2))
    past_after = f.smoothed_track()
    assert track_err(past_after, truth, 30) < 0.3 < track_err(past_before, truth, 30)
    assert err(live, truth[-1]) < err(published[-1], truth[-1])
    for p, (t, x, y, h, cov, floor, source) in zip(published, snapshot):
        assert (p.t, p.x, p.y, p.heading, p.floor, p.source) == (t, x, y, h, floor, source)
        np.testing.assert_array_equal(p.cov, cov)
    with pytest.raises(ValueError):
        published[-1].cov[0, 0] = 0.0  # read-only: nobody can change a published pose


def test_fix_older_than_the_window_is_rejected():
    events, truth = walk(np.zeros(200))  # 100 s of walking
    f = TrackFusion(no_mag(lag_s=30.0))
    f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
    for ev in events:
        f.add_step(ev)
    assert f.add_fix(CheckpointFix(t=events[10].t, x=truth[11, 0], y=truth[11, 1])) is None
    assert f.rejected["too_old"] == 1
    assert f.add_fix(CheckpointFix(t=-60.0, x=0.0, y=0.0)) is None
    assert f.rejected["before_start"] == 1
    assert f.add_fix(CheckpointFix(t=events[-20].t, x=truth[-20, 0], y=truth[-20, 1])) is not None
    # newer than the latest step: attaches to the latest pose
    assert f.add_fix(CheckpointFix(t=events[-1].t + 5.0, x=truth[-1, 0], y=truth[-1, 1])) is not None
    assert f.events[-1].values["row"] == len(events)


def test_marginalisation_keeps_the_state_bounded():
    n = 5000
    rng = np.random.default_rng(7)
    turns = np.zeros(n)
    turns[rng.integers(0, n, 200)] = math.pi / 2
    events, truth = walk(np.cumsum(turns), turn_bias=0.05 * DEG)
    settings = no_mag(lag_s=30.0)
    f = TrackFusion(settings)
    f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
    # poses in the window, the step-length scales opened in it, + slack for fix variables
    bound = settings.lag_s / STEP_DT + settings.lag_s / settings.length_scale_interval_s + 1 + 5
    worst = 0
    for k, ev in enumerate(events):
        f.add_step(ev)
        if (k + 1) % 40 == 0:  # every 20 s: a pose is fixed on both sides before it leaves the 30 s window
            f.add_fix(CheckpointFix(t=ev.t, x=truth[k + 1, 0], y=truth[k + 1, 1], sigma=0.3))
            f.add_fix(UwbRange(t=ev.t, anchor_x=truth[k + 1, 0] + 5.0, anchor_y=truth[k + 1, 1], range=5.0, sigma=0.2,
                               anchor=f"A{k // 400}"))
        if k % 250 == 0:
            worst = max(worst, f.window_variables)
    assert worst <= bound
    track = f.smoothed_track()
    assert len(track["t"]) == n + 1
    np.testing.assert_array_equal(track["index"], np.arange(n + 1))
    assert np.all(np.isfinite(track["x"])) and np.all(np.isfinite(track["y"]))
    assert np.max(track_err(track, truth, np.arange(n + 1))) < 1.0  # frozen poses are smoothed, not raw PDR


# ------------------------------------------------------------------ compass factor (why it is on by default)


def test_compass_factor_bounds_gyro_drift():
    """Gyro drift of 0.3°/step over 400 steps (120°): the compass keeps the heading; without it the track is lost."""
    rng = np.random.default_rng(1)
    h = np.repeat([0.0, math.pi / 2, math.pi, -math.pi / 2], 100)
    mag = h + rng.normal(0.0, 5 * DEG, len(h))
    events, truth = walk(h, turn_bias=0.3 * DEG, mag=mag)
    errors = {}
    for on in (True, False):
        f = TrackFusion(FusionSettings(use_mag_heading=on))
        f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
        for ev in events:
            last = f.add_step(ev)
        errors[on] = err(last, truth[-1])
    assert errors[True] < 3.0
    assert errors[False] > 5 * errors[True]


def test_robust_compass_kernel_limits_an_undetected_disturbance():
    """40 steps where the compass reads 50° off but claims 5° (missed by the PDR's disturbance gate):
    Cauchy (the default) bends the track far less than Huber or plain least squares."""
    rng = np.random.default_rng(2)
    h = np.repeat([0.0, math.pi / 2, 0.0], [60, 40, 60])
    mag = h + rng.normal(0.0, 3 * DEG, len(h))
    mag[60:100] += 50 * DEG
    events, truth = walk(h, mag=mag)
    errors = {}
    for kernel in ("cauchy", "huber", "gaussian"):
        f = TrackFusion(FusionSettings(mag_kernel=kernel))
        f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
        for ev in events:
            last = f.add_step(ev)
        errors[kernel] = np.max(track_err(f.smoothed_track(), truth, np.arange(len(h) + 1)))
    assert FusionSettings().mag_kernel == "cauchy"
    assert errors["cauchy"] < 0.3 * errors["gaussian"]
    assert errors["cauchy"] < 0.3 * errors["huber"]


def test_compass_recovers_the_heading_after_a_gap():
    """The compass is missing for 150 steps while the gyro drifts 0.3°/step (45°): once it returns, the
    (redescending) default kernel must still pull the heading back rather than distrust it for good."""
    rng = np.random.default_rng(3)
    h = np.repeat([0.0, math.pi / 2, math.pi, -math.pi / 2], 100)
    mag = h + rng.normal(0.0, 5 * DEG, len(h))
    mag[100:250] = np.nan
    events, truth = walk(h, turn_bias=0.3 * DEG, mag=mag)
    f = TrackFusion()
    f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
    for ev in events:
        last = f.add_step(ev)
    assert abs(math.remainder(last.heading - h[-1], 2 * math.pi)) < 5 * DEG
    assert np.max(track_err(f.smoothed_track(), truth, np.arange(len(h) + 1))) < 5.0


# ------------------------------------------------------------------ bad input


def test_bad_input_is_reported_clearly():
    with pytest.raises(ValueError, match="GnssFix.x"):
        GnssFix(t=0.0, x=math.nan, y=0.0, accuracy=3.0)
    with pytest.raises(ValueError, match="UwbRange.sigma"):
        UwbRange(t=0.0, anchor_x=0.0, anchor_y=0.0, range=1.0, sigma=0.0)
    with pytest.raises(ValueError, match="FusionSettings.gnss_kernel"):
        FusionSettings(gnss_kernel="l1")
    f = TrackFusion()
    with pytest.raises(RuntimeError, match="start"):
        f.add_fix(CheckpointFix(t=0.0, x=0.0, y=0.0))
    events, _ = walk(np.zeros(3))
    f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.1)
    f.add_step(events[1])
    with pytest.raises(ValueError, match="not after the previous pose"):
        f.add_step(events[0])
    with pytest.raises(TypeError):
        f.add_fix((1.0, 2.0))
    f.add_step(events[2])
    assert f.live.steps == 2


def test_bench_fusion_runs_and_converges():
    report = bench_fusion(steps=400, fix_every=100, seed=1)
    assert report["steps"] == 400
    assert report["final_error_m"] < 1.5  # the last step is a checkpoint step
    assert report["smoothed_rmse_m"] < 3.0


def test_fusion_command_prints_json():
    import json

    import typer
    from typer.testing import CliRunner

    from service.fusion.bench import fusion_command

    app = typer.Typer()
    app.command("fusion")(fusion_command)
    result = CliRunner().invoke(app, ["--steps", "200", "--fix-every", "50", "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["steps"] == 200 and report["fix_every"] == 50
    for key in ("median_update_ms", "p99_update_ms", "first_1000_median_ms", "last_1000_median_ms",
                "ratio_last_first", "total_s", "final_error_m"):
        assert math.isfinite(report[key])


def test_a_3d_uwb_range_becomes_the_horizontal_distance_for_the_tags_height():
    from service.fusion.fixes import UwbRange

    r = UwbRange(t=1.0, anchor_x=0.0, anchor_y=0.0, range=5.0, sigma=0.1, anchor="A1", anchor_z=4.2)
    h = r.at_height(1.2)  # 3 m below the anchor: a 3-4-5 triangle
    assert h.range == pytest.approx(4.0) and math.isnan(h.anchor_z)
    assert h.sigma == pytest.approx(0.1 * 5.0 / 4.0)  # dr_h/dr = r / r_h
    assert h.at_height(0.0) is h  # horizontal already: unchanged
    short = r.at_height(-10.0)  # noise made the range shorter than the height difference
    assert short.range == 0.0 and short.sigma >= 0.1
    flat = UwbRange(t=1.0, anchor_x=0.0, anchor_y=0.0, range=5.0, sigma=0.1)
    assert flat.at_height(1.2) is flat  # no anchor height configured: taken as horizontal


# ------------------------------------------------------------------ issue 12: indoor GNSS, display, floors, stairs


def test_gnss_below_ground_is_not_evidence_and_fixes_come_at_most_every_interval():
    events, truth = walk(np.zeros(40), floors=np.full(40, -2))
    f = TrackFusion(no_mag())
    f.start(0.0, 0.0, 0.0, heading=5 * DEG, heading_sigma=10 * DEG, position_sigma=1.0, floor=-2)
    for ev in events:
        live = f.add_step(ev)
    t = events[-1].t
    good = GnssFix(t=t, x=truth[-1, 0], y=truth[-1, 1], accuracy=3.0)
    assert f.add_fix(good) is None and f.rejected["gnss_below_ground"] == 1
    assert f.live is live
    above = TrackFusion(no_mag(gnss_min_interval_s=5.0))
    above.start(0.0, 0.0, 0.0, heading=5 * DEG, heading_sigma=10 * DEG, position_sigma=1.0)
    for ev in walk(np.zeros(40))[0]:
        above.add_step(ev)
    assert above.add_fix(good) is not None
    assert above.add_fix(dataclasses.replace(good, t=t - 1.0)) is None and above.rejected["gnss_interval"] == 1
    # what the settings say a basement is: floors below gnss_lowest_floor; None turns the rule off
    anywhere = TrackFusion(no_mag(gnss_lowest_floor=None))
    anywhere.start(0.0, 0.0, 0.0, heading=5 * DEG, heading_sigma=10 * DEG, position_sigma=1.0, floor=-2)
    for ev in events:
        anywhere.add_step(ev)
    assert anywhere.add_fix(good) is not None


def test_published_pose_does_not_jump_at_gnss_and_converges_within_steps():
    """A GNSS fix moves the graph's estimate at once; the published pose follows over the next
    steps instead of jumping (no step-by-step zig-zag); a checkpoint moves it at once."""
    events, truth = walk(np.zeros(80))
    f = TrackFusion(no_mag(display_gain=0.5))
    g = TrackFusion(no_mag(display_gain=1.0))
    for x in (f, g):
        x.start(0.0, 0.0, 0.0, heading=6 * DEG, heading_sigma=10 * DEG, position_sigma=0.3)
    for ev in events[:40]:
        shown, raw = f.add_step(ev), g.add_step(ev)
    assert (shown.x, shown.y) == pytest.approx((raw.x, raw.y), abs=1e-9)  # nothing to smooth yet
    fix = GnssFix(t=events[39].t, x=truth[40, 0], y=truth[40, 1], accuracy=2.0)
    after_f, after_g = f.add_fix(fix), g.add_fix(fix)
    assert (after_f.x, after_f.y) == (shown.x, shown.y)  # held
    assert err(after_g, truth[40]) < 0.6 * err(raw, truth[40])  # the graph moved
    gaps = []
    for ev in events[40:50]:
        a, b = f.add_step(ev), g.add_step(ev)
        gaps.append(math.hypot(a.x - b.x, a.y - b.y))
    assert gaps[0] < 0.6 * err(raw, truth[40]) and gaps[-1] < 0.01 * gaps[0] + 0.01  # halved per step
    assert all(b < a for a, b in zip(gaps, gaps[1:]))
    snap = f.add_fix(CheckpointFix(t=events[49].t, x=truth[50, 0] + 1.0, y=truth[50, 1], sigma=0.05))
    est = f.smoothed_track()
    assert (snap.x, snap.y) == pytest.approx((est["x"][-1], est["y"][-1]), abs=1e-9)


def test_floor_change_without_a_step_is_published_and_kept_in_the_smoothed_track():
    events, _ = walk(np.zeros(20))
    f = TrackFusion(no_mag())
    f.start(0.0, 0.0, 0.0, heading=0.0, heading_sigma=0.05, position_sigma=0.3)
    for ev in events[:10]:
        last = f.add_step(ev)
    lift = f.set_floor(events[9].t + 20.0, -2)  # a lift ride
    assert lift.floor == -2 and (lift.x, lift.y) == (last.x, last.y)
    assert f.add_fix(GnssFix(t=events[9].t + 21.0, x=last.x, y=last.y, accuracy=5.0)) is None
    assert f.rejected["gnss_below_ground"] == 1  # in the basement now, though no step has said so
    nxt = f.add_step(dataclasses.replace(events[10], t=events[9].t + 25.0, floor=-2))
    assert nxt.floor == -2
    sm = f.smoothed_track()
    i = int(np.searchsorted(sm["t"], events[9].t + 20.0))
    assert sm["floor"][i] == -2 and sm["t"][i] == events[9].t + 20.0 and sm["floor"][i - 1] == 0
    assert np.all(np.diff(sm["t"]) >= 0) and len(sm["t"]) == 12 + 1


def test_turns_on_stairs_give_way_to_the_compass():
    """A spiral staircase: the phone pitches and the forward axis's yaw jumps; a spurious 60° turn
    on a stair step is undone by the compass when stair turns are loose, not when they are tight."""
    h = np.zeros(80)
    mag = h + np.random.default_rng(5).normal(0.0, 3 * DEG, 80)
    events, truth = walk(h, mag=mag, mag_sigma=20 * DEG)
    bad = [dataclasses.replace(ev, on_stairs=20 <= k < 30,
                               heading_change=ev.heading_change + (60 * DEG if k == 25 else 0.0)) for k, ev in enumerate(events)]
    errs = {}
    for stairs_sigma in (0.0, 10 * DEG):
        f = TrackFusion(FusionSettings(stairs_turn_sigma_rad=stairs_sigma, display_gain=1.0))
        f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
        for ev in bad:
            last = f.add_step(ev)
        errs[stairs_sigma] = err(last, truth[-1])
    assert errs[10 * DEG] < 0.5 * errs[0.0]


def test_compass_that_does_not_turn_with_the_gyro_is_left_out():
    """Walking past a steel column: over 10 steps the compass swings 40° and back while the gyro
    says straight on (the field bends from metre to metre, unseen in 0.5 s epochs). The window
    gate drops those compass steps; a uniform field, however biased, passes."""
    h = np.zeros(90)
    mag = h + np.random.default_rng(4).normal(0.0, 2 * DEG, 90)
    mag[40:50] += np.radians(40.0) * np.sin(np.linspace(0, np.pi, 10))
    events, truth = walk(h, mag=mag, mag_sigma=10 * DEG)
    gated = TrackFusion(FusionSettings(display_gain=1.0))
    plain = TrackFusion(FusionSettings(display_gain=1.0, mag_window_gate_rad=math.inf))
    for f in (gated, plain):
        f.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
        for ev in events:
            last = f.add_step(ev)
    assert gated.rejected["compass_window"] >= 5 and plain.rejected["compass_window"] == 0
    worst = {n: np.max(track_err(f.smoothed_track(), truth, np.arange(91))) for n, f in (("gated", gated), ("plain", plain))}
    assert worst["gated"] < 0.7 * worst["plain"]
    biased = TrackFusion(FusionSettings())
    biased.start(0.0, 0.0, 0.0, 0.0, heading_sigma=0.05)
    for ev in walk(square(), mag=square() + 20 * DEG)[0]:
        biased.add_step(ev)
    assert biased.rejected["compass_window"] == 0

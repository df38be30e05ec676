"""A change of grip mid-walk (pdr/grip.py): the heading of travel survives it.

Synthetic walks, so they can fail in both directions: a walker going east (ENU yaw 0) with a
flat phone, a 1.8 Hz vertical bounce and the fore-aft swing a quarter period ahead of it (the
gait's phase the walking-direction test reads), the earth's field, and a gyro that sees
every turn of the phone. Halfway through, the phone is turned in the hand by 90° about the
screen normal within half a second (portrait to landscape) while the walker goes straight on.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from pdr import quaternion as quat
from pdr.angles import wrap
from pdr.grip import GripSettings, GripTracker
from pdr.heading import HeadingEstimator, HeadingSettings
from pdr.walking_direction import WalkingAxis

RATE = 50.0
STEP_HZ = 1.8
FIELD = np.array([0.0, 20.0, -45.0])  # µT, ENU: north and down


def _walker_yaw(t, t_grip: float, turn_deg: float):
    """The walker's own heading: ``turn_deg`` in 1.5 s from half a second before the re-grip."""
    r = np.clip((t - t_grip + 0.5) / 1.5, 0.0, 1.0)
    return math.radians(turn_deg) * (3 * r**2 - 2 * r**3)


def _walk(regrip_deg: float, seconds: float = 120.0, seed: int = 0, raised_deg: float = 0.0, axis=(0.0, 0.0, 1.0),
          turn_deg: float = 0.0, t_grip: float | None = None, start: float = 2.0):
    """``raised_deg``: the phone's long axis that far above the horizon (0: flat), so that its
    screen normal, the axis of the re-grip, is tilted by as much from the vertical; ``axis``
    the body axis of the re-grip; ``turn_deg`` a turn of the walker at the same time;
    ``t_grip`` when the re-grip starts (default: halfway); ``start`` when the walk starts (the
    walker stands before it; the first step a second later)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / RATE)
    w = 2.0 * math.pi * STEP_HZ
    t_grip = seconds / 2 if t_grip is None else t_grip
    ramp = np.clip((t - t_grip) / 0.5, 0.0, 1.0)
    dev_yaw = math.radians(regrip_deg) * (3 * ramp**2 - 2 * ramp**3)  # the phone's turn in the hand (smooth)
    yaw_rate = np.gradient(dev_yaw, t)
    psi_w = _walker_yaw(t, t_grip, turn_deg)
    walking = t > start
    fwd = np.where(walking, 1.5 * np.sin(w * t + math.pi / 2), 0.0)  # along the walk
    side = np.where(walking, 0.3 * np.sin(0.5 * w * t), 0.0)  # the body's sway, half the step rate
    up = 9.81 + np.where(walking, 1.4 * np.sin(w * t), 0.0)
    c, sn = np.cos(psi_w), np.sin(psi_w)
    f_nav = np.column_stack([c * fwd - sn * side, sn * fwd + c * side, up])
    q_hand = quat.multiply(quat.from_yaw(-math.pi / 2), quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(raised_deg)))
    a = np.asarray(axis, float)
    q_in_hand = np.array([quat.multiply(q_hand, quat.from_axis_angle(a, y)) for y in dev_yaw])
    q = np.array([quat.multiply(quat.from_yaw(p), qh) for p, qh in zip(psi_w, q_in_hand)])  # body y along the walk at the start
    acc = np.array([quat.rotate(quat.conjugate(qi), f) for qi, f in zip(q, f_nav)]) + rng.normal(0, 0.05, (t.size, 3))
    mag = np.array([quat.rotate(quat.conjugate(qi), FIELD) for qi in q]) + rng.normal(0, 0.3, (t.size, 3))
    walker_rate = np.column_stack([np.zeros_like(t), np.zeros_like(t), np.gradient(psi_w, t)])
    gyr = (np.array([quat.rotate(quat.conjugate(qh), wr) for qh, wr in zip(q_in_hand, walker_rate)])
           + np.outer(yaw_rate, a) + rng.normal(0, 0.002, (t.size, 3)))
    steps = np.arange(start + 1.0, seconds - 0.5, 1.0 / STEP_HZ)
    return t, acc, gyr, mag, steps, t_grip


def _headings(settings: HeadingSettings, regrip_deg: float, batch: int = 10, **walk):
    t, acc, gyr, mag, steps, t_grip = _walk(regrip_deg, **walk)
    h = HeadingEstimator(settings)
    out = []
    for i in range(0, t.size, batch):
        sl = slice(i, i + batch)
        due = steps[(steps > t[i] - 1e-9) & (steps <= t[sl][-1])] if i else steps[steps <= t[sl][-1]]
        out.append(h.update(t[sl], acc[sl], gyr[sl], mag[sl], step_times=due))
    tk = np.concatenate([o.t for o in out])
    hd = np.concatenate([o.heading for o in out])
    dsig = np.concatenate([o.heading_change_sigma for o in out])
    return tk, hd, dsig, t_grip, h


def test_a_turn_of_the_phone_in_the_hand_is_not_a_turn_of_the_walker():
    tk, hd, dsig, t_grip, h = _headings(HeadingSettings(), 90.0)
    late = tk > t_grip + 15.0
    err = np.degrees(np.abs(wrap(hd[late])))
    assert h.grip.jumps == 1
    assert math.degrees(abs(wrap(h.grip.offset + math.pi / 2))) < 15.0  # walking = device − 90°
    assert np.median(err) < 10.0 and err.max() < 25.0, (np.median(err), err.max())
    assert np.isinf(dsig[tk > t_grip]).sum() == 1  # the step of the jump: its turn is unknown
    # before the change the texting grip is held exactly
    assert np.all(np.degrees(np.abs(wrap(hd[(tk > 20.0) & (tk < t_grip)]))) < 10.0)


def test_without_detection_the_walk_goes_sideways():
    """The control: the same walk with the detection off ends 90° off (what main did)."""
    s = HeadingSettings(grip=dataclasses.replace(GripSettings(), enabled=False))
    tk, hd, _, t_grip, h = _headings(s, 90.0)
    err = np.degrees(np.abs(wrap(hd[tk > t_grip + 15.0])))
    assert h.grip.jumps == 0 and np.median(err) > 70.0


def test_a_phone_raised_in_the_hand_and_turned_to_landscape_is_caught_as_it_turns():
    """The phone held as on the IPIN walks (long axis 55° up, so the screen normal, the axis of
    the turn, is 35° from the vertical): the tilt changes by about 70° within the half second
    and ω jumps then, instead of some 8 steps and a 3 s window later (the control below)."""
    tk, hd, dsig, t_grip, h = _headings(HeadingSettings(), 90.0, raised_deg=55.0)
    soon = (tk > t_grip + 1.5) & (tk < t_grip + 8.0)
    err = np.degrees(np.abs(wrap(hd)))
    assert h.grip.regrips == 1 and h.grip.jumps == 1
    assert np.median(err[soon]) < 15.0 and np.median(err[tk > t_grip + 15.0]) < 10.0, (err[soon], err[tk > t_grip + 15.0])
    assert np.isinf(dsig[tk > t_grip]).sum() == 1
    control = HeadingSettings(grip=dataclasses.replace(GripSettings(), regrip_tilt=math.pi))
    tk, hd, _, _, hc = _headings(control, 90.0, raised_deg=55.0)
    assert hc.grip.regrips == 0 and np.median(np.degrees(np.abs(wrap(hd[soon])))) > 45.0


def test_the_tilt_before_a_regrip_comes_from_a_step_the_turn_had_not_reached():
    """The turn to landscape starting late in a step: that step's mean attitude is already a few
    degrees turned, less than the settle test sees, so a reference taken from it makes ω short
    by as much (12° and 18° at these two phases; the robustness suite's grip_z on IPIN trial 05
    rep 04, 9° of tilt kept where 10° were allowed, refused the re-grip). A step is the
    reference only once the next one kept its tilt."""
    for t_grip in (20.0, 20.5):
        tk, hd, _, _, h = _headings(HeadingSettings(), 90.0, raised_deg=55.0, t_grip=t_grip, seconds=40.0)
        after = np.degrees(np.abs(wrap(hd[(tk > t_grip + 1.5) & (tk < t_grip + 4.0)])))
        assert h.grip.regrips == 1 and after.max() < 5.0, (t_grip, after)


def test_a_walk_that_starts_in_landscape_is_caught_in_its_first_steps():
    """The phone turned to landscape while the walker stands, 7 s before the first step: no
    walking step before it to compare the tilt with and no sample of the portrait grip left in
    the window, so the walking axis must tell, and at the start ω = 0 is a prior, not evidence:
    ``regrip_steps`` (4) measurements that agree make the jump, not ``steps`` (8; then the
    first 7 steps went 90° off)."""
    tk, hd, _, _, h = _headings(HeadingSettings(), 90.0, raised_deg=55.0, t_grip=1.0, start=8.0, seconds=45.0)
    err = np.degrees(np.abs(wrap(hd)))
    assert h.grip.jumps == 1 and h.grip.regrips == 0
    assert np.median(err[(tk > 10.5) & (tk < 13.5)]) < 10.0 and err[tk > 10.5].max() < 15.0, err[:15]


def test_a_phone_turned_just_before_the_first_step_is_caught_from_the_standing_attitude():
    """The phone turned to landscape 1 s before the first step (IPIN route 21 rep 03 under
    hold_z: 1.5 s): the samples before the first walking step's own, within the step's window,
    still hold the portrait grip the walker stood in; they are the reference, and the second
    step's tilt (the first that is settled) is the re-grip. Without them the walking axis
    needed 4 steps."""
    tk, hd, dsig, _, h = _headings(HeadingSettings(), 90.0, raised_deg=55.0, t_grip=7.0, start=8.0, seconds=45.0)
    err = np.degrees(np.abs(wrap(hd)))
    assert h.grip.regrips == 1 and h.grip.jumps == 1
    assert err[tk > 9.5].max() < 5.0, err[:10]
    # the walker standing still in the same grip throughout: no re-grip, no jump
    tk, hd, _, _, h = _headings(HeadingSettings(), 0.0, raised_deg=55.0, start=8.0, seconds=45.0)
    assert h.grip.jumps == 0 and np.degrees(np.abs(wrap(hd))).max() < 10.0


def test_a_screen_raised_while_the_walker_turns_leaves_the_offset():
    """The walker turns 90° left while raising the screen by 60° (about the phone's x axis): the
    tilt changes, but a turn about x leaves the heading vector, so ω stays 0 and the walker's
    own turn is not taken for the phone's (the re-grip's axis and angle come from the tilt)."""
    tk, hd, _, t_grip, h = _headings(HeadingSettings(), 60.0, raised_deg=55.0, axis=(1.0, 0.0, 0.0), turn_deg=90.0)
    err = np.degrees(np.abs(wrap(hd - _walker_yaw(tk, t_grip, 90.0))))
    assert h.grip.jumps == 0 and h.grip.offset == 0.0
    assert np.median(err[tk > t_grip + 2.0]) < 10.0, err[tk > t_grip + 2.0]


def test_a_raised_phone_that_stays_in_the_hand_is_not_a_regrip():
    tk, hd, _, _, h = _headings(HeadingSettings(), 0.0, raised_deg=55.0)
    assert h.grip.jumps == 0 and h.grip.offset == 0.0
    assert np.degrees(np.abs(wrap(hd[tk > 10.0]))).max() < 10.0


def test_a_walk_without_a_change_keeps_the_texting_grip():
    tk, hd, _, _, h = _headings(HeadingSettings(), 0.0)
    assert h.grip.jumps == 0 and h.grip.offset == 0.0
    assert np.degrees(np.abs(wrap(hd[tk > 10.0]))).max() < 10.0


def test_batching_does_not_change_the_headings():
    a = _headings(HeadingSettings(), 90.0, batch=10)
    b = _headings(HeadingSettings(), 90.0, batch=997)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_measurements_that_do_not_look_like_walking_are_not_used():
    g = GripTracker()
    waved = WalkingAxis(math.pi / 2, 0.9, 0.9, 5.0)  # a calibration wave: σ_z 5 m/s²
    no_phase = WalkingAxis(math.pi / 2, 0.9, 0.1, 1.0)
    for _ in range(20):
        assert g.step(waved) == (0.0, False) and g.step(no_phase) == (0.0, False)
    # stairs: the phase test turns round, the axis does not: no jump
    for _ in range(20):
        assert g.step(WalkingAxis(math.pi - 0.1, 0.9, 0.9, 1.0))[1] is False
    assert g.offset == 0.0


def test_a_steep_phone_keeps_its_heading_through_a_tilt_error():
    """A phone whose long axis stands 85° above the horizon, pointing north, seen by a levelling
    filter that is 3° off in roll: the long axis's yaw alone is 30° off (its horizontal part is
    short), the heading vector that lets the back of the phone take over is off by < 4°."""
    from pdr.heading_kernels import level_and_compass

    q_true = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(85.0))
    q_err = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), math.radians(3.0))
    q = quat.multiply(q_err, q_true).reshape(1, 4)
    acc = np.zeros((1, 3))
    s0 = math.sin(HeadingSettings().upright_from) ** 2

    def yaw_error(upright):
        fwd = np.array([0.0, 1.0, 0.0, *upright, s0])
        raw = level_and_compass(q, fwd, acc, np.empty((0, 3)), False, 0.0)[0][0]
        return math.degrees(abs(wrap(raw - math.pi / 2)))

    assert yaw_error((0.0, 0.0, 0.0)) > 20.0
    assert yaw_error(HeadingSettings().upright_axis) < 4.0
    # at the development walks' usual 55°, the upright axis does not count: the same yaw
    q55 = quat.multiply(q_err, quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(55.0))).reshape(1, 4)
    a = level_and_compass(q55, np.array([0.0, 1.0, 0.0, 0.0, 0.0, -1.0, s0]), acc, np.empty((0, 3)), False, 0.0)[0]
    b = level_and_compass(q55, np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, s0]), acc, np.empty((0, 3)), False, 0.0)[0]
    assert a[0] == b[0]

"""The walk gate (service/fusion/walk_gate.py): fixes against dead reckoning from the last trusted fix."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pdr.events import StepEvent
from service.fusion.fixes import CheckpointFix, UwbRange
from service.fusion.settings import FusionSettings
from service.fusion.walk_gate import WalkGate


def east_step(i: int, length: float = 0.7) -> StepEvent:
    """Step ``i`` of a walk due east at one step per 0.6 s."""
    return StepEvent(t=0.6 * i, index=i, length=length, length_sigma=0.05, heading=0.0, heading_sigma=0.05,
                     heading_change=0.0, heading_change_sigma=0.01, dz=0.0, dz_sigma=0.1, floor=0, on_stairs=False,
                     mag_heading=math.nan, mag_heading_sigma=math.inf)


def walked(gate: WalkGate, first: int, last: int, heading_sigma: float = 0.05) -> None:
    """Steps ``first``..``last`` due east, the live heading known to ``heading_sigma`` (rad)."""
    for i in range(first, last + 1):
        gate.add_step(east_step(i), 0.0, heading_sigma)


def new_gate(**over) -> WalkGate:
    gate = WalkGate(FusionSettings(**over))
    gate.start(0.0, 0.0, 0.0, 0.3, 0, 0.0, 0.05)
    return gate


def test_a_fix_where_the_walk_is_trusted_and_a_far_one_is_held_out():
    gate = new_gate()
    walked(gate, 1, 50)  # 35 m east
    here = gate.judge(CheckpointFix(30.0, 35.5, 0.3, sigma=0.3))
    assert here.ok and here.trusted
    far = gate.judge(CheckpointFix(30.0, 100.0, 100.0, sigma=0.01))
    assert not far.ok and far.reason == "walk_gate" and "walked" in far.detail


def test_a_drag_pays_for_its_offset_in_walked_distance():
    """Each fix 5 m beyond the last: after the first, the gate holds them out until the drift
    allowance (walk_gate_drift per metre walked) has grown by the offset."""
    gate = new_gate()
    walked(gate, 1, 150)
    offset, taken, i = 0.0, 0, 150
    for _ in range(10):
        x = gate.point[0].x + offset + 5.0
        fix = CheckpointFix(0.6 * i, x, 0.0, sigma=0.5)
        v = gate.judge(fix)
        if v.ok:
            gate.take(fix, v)
            taken += 1
            offset += 5.0
        walked(gate, i + 1, i + 5)  # 3 s, 3.5 m
        i += 5
    assert taken <= 2
    assert offset <= 10.0  # the same drag on the graph alone: 50 m


def test_a_step_length_error_beyond_the_drift_allowance_is_locked_out_in_the_end():
    """The known limit (walk_gate.py, *What it does not stop*): dead reckoning 7.5 % short, along
    the track where its covariance is small. The first landmark reaches the graph on the drift
    allowance but is not trusted; the reference stays short, and a landmark 400 m on is held out."""
    gate = new_gate()
    walked(gate, 1, 150)
    first = CheckpointFix(90.0, gate.point[0].x * 1.075, 0.0, sigma=0.3)
    v = gate.judge(first)
    assert v.ok and not v.trusted
    gate.take(first, v)
    walked(gate, 151, 700)
    late = gate.judge(CheckpointFix(420.0, gate.point[0].x * 1.075, 0.0, sigma=0.3))
    assert not late.ok and late.reason == "walk_gate"


def test_a_range_the_walk_cannot_have_is_held_out():
    gate = new_gate()
    walked(gate, 1, 30)  # 21 m east of an anchor at the origin
    assert gate.judge(UwbRange(18.0, 0.0, 0.0, 21.2, 0.1)).ok
    v = gate.judge(UwbRange(18.0, 0.0, 0.0, 60.0, 0.05))
    assert not v.ok and v.reason == "walk_gate"


def test_off_lets_everything_through():
    gate = new_gate(walk_gate_probability=None)
    walked(gate, 1, 10)
    assert gate.judge(CheckpointFix(6.0, 1e7, 0.0, sigma=0.5)).ok


def test_a_heading_made_certain_midway_leaves_the_reference_a_covariance_and_a_range_a_verdict():
    """Walk east with the heading uncertain (σθ = 1 rad), then west with the graph's heading
    nearly exact: the reference's θθ shrinks while its cross terms stay, and its propagated
    position covariance went indefinite (yy = -196 m²); a UWB range with the anchor north was
    then judged with the square root of a negative variance, a ValueError (CI, test_attacks_tls:
    a responder's track lost for 20 s)."""
    gate = WalkGate(FusionSettings())
    gate.start(0.0, 0.0, 0.0, 0.3, 0, 0.0, 1.0)
    walked(gate, 1, 20, heading_sigma=1.0)
    for i in range(21, 41):
        gate.add_step(dataclasses.replace(east_step(i), heading=math.pi), math.pi, 0.001)
    assert all(np.linalg.eigvalsh(r.cov)[0] >= -1e-9 for r in gate._rows)
    xx, xy, xt, yy, yt, tt = gate._state[4]
    full = np.array([[xx, xy, xt], [xy, yy, yt], [xt, yt, tt]])
    assert np.linalg.eigvalsh(full)[0] >= -1e-9 * np.abs(full).max()  # the reference's whole (x, y, θ) stays PSD
    p = gate.point[0]
    v = gate.judge(UwbRange(t=0.6 * 40, anchor_x=p.x, anchor_y=p.y + 10.0, range=10.0, sigma=0.1))
    assert v.ok


def test_a_heading_error_revealed_by_two_fixes_lets_both_in():
    """Dead reckoning walks due east; the walker went 30° north of it (a heading error the
    graph's heading sigma does not admit). The first landmark, 10.5 m off after 21 m, is held
    out; the second shows the leg between them turned, not shifted: it is let in, trusted, with
    the first for the graph to take first."""
    gate = new_gate()
    true = np.array([math.cos(math.radians(30)), math.sin(math.radians(30))])
    walked(gate, 1, 30)
    a = CheckpointFix(0.6 * 30, *(21.0 * true), sigma=0.3)
    assert not gate.judge(a).ok
    walked(gate, 31, 60)
    v = gate.judge(CheckpointFix(0.6 * 60, *(42.0 * true), sigma=0.3))
    assert v.ok and v.trusted and v.earlier is a
    assert v.info["turn_deg"] == pytest.approx(30.0, abs=1.0)


@pytest.mark.parametrize("shift", [(0.0, 8.0), (8.0, 0.0)])
def test_two_fixes_one_offset_from_the_walk_are_a_shift_not_a_turn(shift):
    """A drag's signature (both fixes the same offset from dead reckoning, across or along the
    track) reveals no turn: the second is judged as if alone (here held out, or let through on
    the drift allowance untrusted), never trusted, and the first stays out."""
    gate = new_gate()
    walked(gate, 1, 30)
    p = gate.point[0]
    assert not gate.judge(CheckpointFix(0.6 * 30, p.x + shift[0], p.y + shift[1], sigma=0.3)).ok
    walked(gate, 31, 40)
    p = gate.point[0]
    v = gate.judge(CheckpointFix(0.6 * 40, p.x + shift[0], p.y + shift[1], sigma=0.3))
    assert not v.trusted and v.earlier is None and "turn_deg" not in v.info


def test_the_live_track_turns_at_the_second_fix_of_a_heading_error():
    """Issue 27, point 5, through the estimator: the PDR's absolute heading and its gyro agree on a
    walk 30° off the truth (a grip it did not notice), no compass; landmarks every 20 steps. Before
    the gate knew turns, every landmark was held out and the live track ended tens of metres off;
    now the live heading is right from the second landmark on and the track stays near the truth."""
    from service.fusion.estimators import FusionEstimator

    h = np.repeat([0.0, math.pi / 2, math.pi, -math.pi / 2], 40)
    off = math.radians(30.0)
    est = FusionEstimator(FusionSettings())
    est.start(0.0, 0.0, 0.0, off, 0.2, 0.3, 0)
    pos, errors, headings = np.zeros(2), [], []
    for k, th in enumerate(h):
        turn = 0.0 if k == 0 else th - h[k - 1]
        ev = dataclasses.replace(east_step(k + 1, 0.8), heading=th + off, heading_change=turn)
        pos = pos + 0.8 * np.array([math.cos(th), math.sin(th)])
        p = est.add_step(ev)
        errors.append(math.hypot(p.x - pos[0], p.y - pos[1]))
        if (k + 1) % 20 == 0:
            out = est.add_fix(CheckpointFix(ev.t + 1e-3, float(pos[0]), float(pos[1]), sigma=0.3))
            if k + 1 >= 40:
                assert out.verdict == "applied"
                headings.append(abs(math.remainder(out.pose.heading - th, 2 * math.pi)))
    assert max(headings) < math.radians(3.0)
    assert max(errors[45:]) < 1.0


def _walk_after_a_pdr_heading_jump(fix_first: bool = False):
    """A walk due east; the PDR's heading starts 160° off with σ 15° (its compass offset taken in
    a steel stretch), and at step 31 its offset restarts onto the truth (a 160° jump the gyro did
    not see). No compass reading reaches the graph (the PDR holds them in the steel): the PDR's
    heading is its only absolute evidence."""
    from service.fusion.estimators import FusionEstimator

    off = math.radians(160.0)
    est = FusionEstimator(FusionSettings())
    est.start(0.0, 0.0, 0.0, off, math.radians(15.0), 0.3, 0)
    if fix_first:
        for i in range(1, 10):
            est.add_step(dataclasses.replace(east_step(i), heading=off, heading_sigma=math.radians(15.0)))
        here = est.add_step(dataclasses.replace(east_step(10), heading=off, heading_sigma=math.radians(15.0)))
        assert est.add_fix(CheckpointFix(6.0 + 1e-3, here.x, here.y, sigma=0.3)).verdict == "applied"
    poses = []
    for i in range(11 if fix_first else 1, 81):
        wrong = i <= 30
        ev = dataclasses.replace(east_step(i), heading=off if wrong else 0.0,
                                 heading_sigma=math.radians(15.0 if wrong else 20.0))
        poses.append(est.add_step(ev))
    return est, poses


def test_a_graph_that_started_on_a_wrong_pdr_heading_restarts_when_the_pdr_heading_jumps():
    """The graph cannot turn 160° by itself: the PDR heading's factors, all that far from it, are
    what the robust kernel ignores and the wandering offset absorbs. When the PDR's heading jumps beyond its gyro turn (its compass offset
    restarted), the graph restarts on it: not a failure (degraded stays 0), a ``restarted`` event.
    Measured on T21r02 under the suite's phone50_steel draw: live p75 22.0 m against 3.0 m dead
    reckoning before, 3.1 m after."""
    est, poses = _walk_after_a_pdr_heading_jump()
    restarts = [e for e in est.fusion.events if e.kind == "restarted"]
    assert len(restarts) == 1 and restarts[0].what == "heading" and "jumped" in restarts[0].detail
    assert est.degraded == 0
    assert abs(math.remainder(poses[-1].heading, 2 * math.pi)) < math.radians(10.0)
    assert poses[-1].x - poses[35].x > 0.9 * 0.7 * 44  # walking east again


def test_a_graph_whose_heading_rests_on_a_precise_fix_does_not_restart_on_a_pdr_jump():
    """With a checkpoint besides the start, two positions fix the graph's heading; a PDR jump alone
    does not restart it (K = 3: T53r02 +1.1 m when it did)."""
    est, _ = _walk_after_a_pdr_heading_jump(fix_first=True)
    assert not [e for e in est.fusion.events if e.kind == "restarted"]

"""Stream continuity and gaps: a restarted wearable, a new device, a counter reset or an outage
continue the same responder's track; every gap is counted in frames and seconds; fixes
re-anchor after a gap; no man-down from an outage (issue 20, parts 2 and 3)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pdr.simulation import SimulatedWalker, WalkerSettings
from service.core.gate import MAX_RESEND_SLACK_S, FrameGate
from service.core.incident_core import CoreSettings, Inbound, IncidentCore
from service.protocol import wire
from service.protocol.incident import default_incident
from tests.walkers import PER_FRAME, RATE_HZ, restamped, walk

N = 5
DT = 0.01


def frame(seq, t0=None, device="phone-A", boot=None):
    start = seq * N * DT if t0 is None else t0
    z = np.zeros((N, 3))
    return wire.ImuBatch(responder="ff1", device=device, boot=boot, seq=seq, t=start + np.arange(N) * DT, acc=z, gyr=z)


# --------------------------------------------------------------------------------------
# The gate: streams by (device, boot, seq)
# --------------------------------------------------------------------------------------
def test_frames_of_another_stream_cannot_take_a_live_stream_over():
    gate = FrameGate()
    released = []
    for s in range(200):  # an honest stream at 20 frames/s, an injected one between its first 100 frames
        released += [(b.device, b.seq) for b in gate.offer(frame(s, boot="honest"), s * 0.05)]
        if s < 100:
            released += [(b.device, b.seq) for b in gate.offer(frame(s % 3, t0=1e6 + s, device="evil"), s * 0.05 + 0.01)]
            released += [(b.device, b.seq) for b in gate.offer(frame(s, t0=1e6 + s, boot="honest"), s * 0.05 + 0.02)]
    assert released == [("phone-A", s) for s in range(200)] and gate.epoch == 0
    gate.expire(13.0)  # 2 * takeover_after_s after the first injected frames, 3 s after the honest stream's last
    # the injected frames were held as a candidate (3 of them) or turned away; the held ones too, in time
    assert gate.counts == {"other_stream": 100, "duplicate": 100} and gate.contested == 100


def test_a_burst_of_new_streams_is_refused_while_the_real_one_speaks_and_a_quick_restart_loses_nothing():
    """Issue 32, attack 6: the responder's own certificate sends a 5 s burst with a new boot id
    at 50 frames/s while the real wearable goes on at 10 frames/s: every real frame is taken,
    the burst is turned away (counted, ``contested``). Then the real wearable restarts 1 s after
    its last frame (sooner than ``takeover_after_s``): its frames wait as the candidate and are
    all released once the old stream's ``takeover_after_s`` of silence prove it gone."""
    gate = FrameGate()
    released = []
    for k in range(100):  # 10 s of the real stream
        released += [(b.boot, b.seq) for b in gate.offer(frame(k, boot="real"), 100.0 + 0.1 * k)]
        if 30 <= k < 80:
            for j in range(5):
                gate.offer(frame(j + 5 * (k - 30), t0=7.0 + 0.05 * j, boot=f"fake{k % 2}"), 100.0 + 0.1 * k + 0.01 * (j + 1))
    gate.expire(120.0)  # the candidate's frames held 2 * takeover_after_s, while the real stream spoke
    assert released == [("real", k) for k in range(100)] and gate.boot == "real" and gate.streams == 1
    assert gate.contested == 250 and gate.counts == {"other_stream": 250}
    # the real wearable restarts: new boot, seq from 0, first frame 1 s after its last one
    last = 120.0
    gate.offer(frame(100, boot="real"), last)
    out = []
    for k in range(40):
        out += gate.offer(frame(k, t0=50.0 + 0.05 * k, boot="again"), last + 1.0 + 0.1 * k)
    assert out == [] and gate.boot == "real"  # 4.9 s of silence: not yet proof of a restart
    for k in range(40, 80):
        out += gate.offer(frame(k, t0=50.0 + 0.05 * k, boot="again"), last + 1.0 + 0.1 * k)
    assert [b.seq for b in out] == list(range(80)) and gate.boot == "again" and gate.lost == 0
    assert gate.contested == 250 and gate.streams == 2
    assert min(rt for rt, why, _ in gate.events if why == "restart") == last + 1.0  # the gap ends at its first frame


def test_an_honest_stream_silent_for_3_s_keeps_its_track_from_a_stream_sending_meanwhile():
    """A phone's Wi-Fi stalls 3 s in a building (or the service is starved under load) while
    frames of another boot arrive on its key: the other stream waits as the candidate, the
    honest one resumes (its frames from the stall arrive in a burst) and keeps its identity,
    loses nothing, and the candidate is turned away and counted. With 2 s of silence taken as
    proof of a restart, the other stream took over and the honest frames were ``old_stream``."""
    gate = FrameGate()
    released = []
    for k in range(30):  # 3 s of the honest stream at 10 frames/s
        released += gate.offer(frame(k, boot="honest"), 100.0 + 0.1 * k)
    for j in range(30):  # 3 s of silence of the honest stream; the other stream sends meanwhile
        released += gate.offer(frame(j, t0=9000.0 + 0.05 * j, boot="forged"), 103.0 + 0.1 * j)
        released += gate.expire(103.05 + 0.1 * j)  # the core's ticks
    for k in range(30, 60):  # the stall ends: its frames in a burst, then live again
        released += gate.offer(frame(k, boot="honest"), 106.0 + 0.001 * (k - 30))
    for k in range(60, 200):
        released += gate.offer(frame(k, boot="honest"), 100.0 + 0.1 * k)
    released += gate.expire(121.0)
    assert [(b.boot, b.seq) for b in released] == [("honest", k) for k in range(200)]
    assert gate.boot == "honest" and gate.streams == 1 and gate.lost == 0 and gate.gaps == 0
    assert gate.counts == {"other_stream": 30} and gate.contested == 30 and not gate.waiting
    assert gate.last_contested == 118.0  # the last held frame (105.9) turned away 2 * takeover_after_s after it ...
    probe = FrameGate()
    for k in range(30):
        probe.offer(frame(k, boot="honest"), 100.0 + 0.1 * k)
    probe.offer(frame(0, t0=9000.0, boot="forged"), 103.0)
    probe.offer(frame(30, boot="honest"), 103.2)  # an honest frame still in flight: no restart yet told apart
    assert probe.last_contested == -math.inf
    probe.offer(frame(31, boot="honest"), 106.0)  # ... but the alarm is on once the honest stream speaks again
    assert probe.last_contested == 106.0 and probe.boot == "honest"


def test_a_candidate_that_does_not_fit_is_asked_for_again_after_it_takes_over():
    """A restart sends more than ``max_candidate`` frames before the old stream's silence is
    proven: the first are held, the rest turned away, and once it takes over the gap in front of
    its next live frame is asked for (the wearable resends it from its keep): nothing lost."""
    gate = FrameGate(max_candidate=8, takeover_after_s=6.0)
    for k in range(10):
        gate.offer(frame(k, boot="old"), 0.1 * k)
    out = []
    for j in range(50):  # the restarted wearable from 1 s after the old one's last frame
        out += gate.offer(frame(j, t0=50.0 + 0.05 * j, boot="new"), 1.9 + 0.1 * j)
    assert out == [] and gate.boot == "old" and gate.counts == {"other_stream": 42}
    out += gate.offer(frame(50, t0=50.0 + 0.05 * 50, boot="new"), 6.95)  # 6 s after the old one's last frame
    assert gate.boot == "new" and [b.seq for b in out] == list(range(8))
    assert gate.ask() == (8, 49) and gate.missing == (8, 49)
    for j in range(8, 50):  # the resend
        out += gate.offer(frame(j, t0=50.0 + 0.05 * j, boot="new"), 7.0 + 0.001 * j)
    assert [b.seq for b in out] == list(range(51)) and gate.lost == 0 and gate.epoch == 1


def test_a_new_boot_is_a_new_stream_at_once_and_the_old_one_is_retired():
    gate = FrameGate()
    for s in range(50):
        gate.offer(frame(s, boot="A"), s * 0.05)
    # the wearable restarted 6 s later (takeover_after_s): seq from 0 again, its clock restarted too
    out = gate.offer(frame(0, t0=0.0, boot="B"), 8.5)
    assert [b.seq for b in out] == [0] and gate.epoch == 1 and gate.streams == 2
    assert gate.boot == "B" and gate.last_seq == 0
    assert gate.gaps == 1 and gate.gap_s == pytest.approx(8.5 - 49 * 0.05)
    # a frame of the old start still in flight is turned away, not switched back to
    assert gate.offer(frame(50, boot="A"), 8.6) == [] and gate.counts == {"old_stream": 1}
    assert [b.seq for b in gate.offer(frame(1, t0=N * DT, boot="B"), 8.7)] == [1]


def test_a_counter_that_restarts_while_time_goes_on_is_a_new_stream_without_a_boot():
    gate = FrameGate()
    for s in range(20):
        gate.offer(frame(s), s * 0.05)
    # seq 0 again, but its samples come after the newest released: not a copy of an old frame
    out = gate.offer(frame(0, t0=20 * N * DT + 1.0), 2.0)
    assert [b.seq for b in out] == [0] and gate.epoch == 1 and gate.counts == {}
    # while a real copy (old seq, old time) is still a duplicate
    assert gate.offer(frame(0, t0=20 * N * DT + 1.0), 2.1) == [] and gate.counts == {"duplicate": 1}


def test_a_seq_far_ahead_is_a_restarted_counter_not_a_loss():
    gate = FrameGate(reorder_window=0, max_seq_jump=1000)
    gate.offer(frame(0), 0.0)
    assert gate.offer(frame(10**9, t0=1.0), 0.1) == [] and gate.counts == {"seq_jump": 1}  # in a live stream
    out = gate.offer(frame(10**9, t0=1.0), 1.0)  # after a silence: the counter restarted
    assert [b.seq for b in out] == [10**9] and gate.lost == 0 and gate.epoch == 1
    gate2 = FrameGate(reorder_window=0, max_seq_jump=1000)
    gate2.offer(frame(0), 0.0)
    gate2.offer(frame(500, t0=500 * N * DT), 0.1)  # within the jump: 499 frames lost, counted
    assert gate2.lost == 499 and gate2.gaps == 1 and gate2.gap_s == pytest.approx(500 * N * DT - (N - 1) * DT)


def test_a_gap_is_asked_for_once_and_held_until_the_resent_frames_fill_it():
    gate = FrameGate()  # reorder_window 4: without the ask, the 5th frame after the gap would skip it
    released = []
    for s in range(10):
        released += [b.seq for b in gate.offer(frame(s), s * 0.05)]
    for k, s in enumerate(range(20, 30)):  # 10..19 missing (a history reply that lost the race)
        released += [b.seq for b in gate.offer(frame(s), 1.0 + k * 0.05)]
        if k == 0:
            assert gate.ask() == (10, 19) and gate.ask() is None  # asked once per gap
    assert gate.missing == (10, 19) and gate.held == 10 and gate.lost == 0
    for k, s in enumerate(range(10, 20)):  # the wearable resends them
        released += [b.seq for b in gate.offer(frame(s), 1.6 + k * 0.01)]
    assert released == list(range(30)) and gate.lost == 0 and gate.missing is None and gate.counts == {}


def test_an_asked_gap_that_is_not_resent_is_lost_after_resend_wait_s_or_max_held():
    gate = FrameGate(resend_wait_s=2.0, max_held=8)
    gate.offer(frame(0), 0.0)
    gate.offer(frame(5), 0.1)
    assert gate.ask() == (1, 4)
    assert gate.expire(2.0) == [] and gate.expire(2.11)[0].seq == 5  # the wait is resend_wait_s, not max_hold_s
    assert gate.lost == 4 and gate.gaps == 1 and gate.missing is None
    gate.offer(frame(10), 3.0)
    assert gate.ask() == (6, 9)
    out = [b.seq for s in range(11, 18) for b in gate.offer(frame(s), 3.0 + (s - 10) * 0.01)]
    assert out == [] and gate.held == 8  # max_held frames wait for the resend
    out = [b.seq for s in range(18, 30) for b in gate.offer(frame(s), 3.2)]
    assert out == list(range(10, 30)) and gate.lost == 8  # one more: the run is lost, and the rest flows


def test_a_burst_beyond_a_gap_waits_whole_for_the_resend():
    """After a standby's takeover the wearable's kept frames come as one burst beyond the gap the
    snapshot left (here 100 frames, a simulated wearable's whole zenoh keep), and the resend of the
    gap a second later. With the default bounds nothing is lost (64 held frames lost the gap:
    test_standby at 4728891 counted 293 frames lost after a takeover, the resend on its way)."""
    gate = FrameGate()
    released = [b.seq for s in range(10) for b in gate.offer(frame(s), 0.01 * s)]
    for s in range(60, 160):  # the burst: everything after the gap at once
        released += [b.seq for b in gate.offer(frame(s), 5.0)]
        if s == 60:
            assert gate.ask() == (10, 59)
    assert released == list(range(10)) and gate.held == 100 and gate.lost == 0
    released += [b.seq for s in range(10, 60) for b in gate.offer(frame(s), 6.0)]  # the resend
    assert released == list(range(160)) and gate.lost == 0 and gate.counts == {}


def test_the_lag_lengthens_the_wait_for_an_asked_gap_only_and_at_most_max_resend_slack_s():
    """``slack`` (the responder's lag) adds to ``resend_wait_s`` for an asked gap, up to
    ``MAX_RESEND_SLACK_S``; a gap nobody asked for still waits ``max_hold_s``; ``max_held``
    still bounds what waits."""
    gate = FrameGate(resend_wait_s=2.0, max_held=64)
    gate.offer(frame(0), 0.0)
    gate.offer(frame(5), 0.1)
    assert gate.ask() == (1, 4)
    assert gate.expire(5.0, slack=3.0) == [] and gate.expire(5.2, slack=3.0)[0].seq == 5 and gate.lost == 4
    capped = FrameGate(resend_wait_s=2.0)
    capped.offer(frame(0), 0.0)
    capped.offer(frame(3), 0.0)
    assert capped.ask() == (1, 2)
    assert capped.expire(2.0 + MAX_RESEND_SLACK_S, slack=1e9) == [] and capped.lost == 0
    assert [b.seq for b in capped.expire(2.1 + MAX_RESEND_SLACK_S, slack=1e9)] == [3] and capped.lost == 2
    unasked = FrameGate(max_hold_s=1.0)
    unasked.offer(frame(0), 0.0)
    unasked.offer(frame(2), 0.0)  # held, not asked for: a reorder within the window
    assert [b.seq for b in unasked.expire(1.1, slack=5.0)] == [2] and unasked.lost == 1
    bounded = FrameGate(resend_wait_s=2.0, max_held=8)
    bounded.offer(frame(0), 0.0)
    bounded.offer(frame(2), 0.0)
    assert bounded.ask() == (1, 1)
    out = [[b.seq for b in bounded.offer(frame(s), 0.1 * s, slack=5.0)] for s in range(3, 11)]
    # the 9th frame held (seq 10) goes past max_held, whatever the slack: seq 1 lost, the rest flows
    assert out == [[]] * 7 + [list(range(2, 11))] and bounded.lost == 1


def test_a_resend_that_comes_in_pieces_waits_from_its_newest_frame():
    """The resend of [0, 11] reaches the gate 2.5 s after the ask (a worker behind), its first
    frame in one round and the rest in the next: the tick between them must not declare the rest
    lost (phase 1 on three workers: 109 of 120 frames, first_seq 0, lost 11, all acknowledged)."""
    gate = FrameGate(resend_wait_s=2.0, ask_from_start=100)
    released = [b.seq for b in gate.offer(frame(12), 0.0)]
    assert gate.ask() == (0, 11)  # the core asks after each frame
    released += [b.seq for s in range(13, 20) for b in gate.offer(frame(s), 0.1 * (s - 12))]
    assert released == []
    released += [b.seq for b in gate.offer(frame(0), 2.5)]
    released += [b.seq for b in gate.expire(3.0)]  # the tick between the two rounds
    assert released == [0] and gate.lost == 0 and gate.missing == (1, 11)
    released += [b.seq for s in range(1, 12) for b in gate.offer(frame(s), 3.1)]
    assert released == list(range(20)) and gate.lost == 0 and gate.counts == {}
    # a resend that stops half-way is lost, counted, resend_wait_s after its newest frame
    cut = FrameGate(resend_wait_s=2.0, ask_from_start=100)
    cut.offer(frame(12), 0.0)
    assert cut.ask() == (0, 11)
    for s in range(13, 20):
        cut.offer(frame(s), 0.1 * (s - 12))
    cut.offer(frame(0), 2.5)
    cut.offer(frame(1), 2.6)
    cut.offer(frame(1), 4.0)  # a copy of a frame already released is no sign of the rest: the wait goes on
    assert cut.expire(4.6) == [] and [b.seq for b in cut.expire(4.7)] == list(range(12, 20)) and cut.lost == 10


def test_a_stream_first_heard_above_seq_0_asks_for_its_beginning_and_counts_what_never_comes():
    """A subscriber declared after the wearable began may be handed seq 12 first (zenoh's
    history reply lost the race): [0, 11] is asked for, and released in order when resent."""
    gate = FrameGate(ask_from_start=100)
    released = [b.seq for s in range(12, 16) for b in gate.offer(frame(s), 0.01 * s)]
    assert released == [] and gate.ask() == (0, 11) and gate.held == 4
    released += [b.seq for s in range(12) for b in gate.offer(frame(s), 0.3)]  # the wearable's resend
    assert released == list(range(16)) and gate.lost == 0 and gate.missing is None
    assert gate.first_of_stream.seq == 0  # the core starts the track at the stream's real first frame
    # not resent within resend_wait_s: the beginning is lost, counted, and the stream flows on
    late = FrameGate(ask_from_start=100)
    late.offer(frame(30, boot="b"), 0.0)
    assert late.ask() == (0, 29) and late.expire(2.1)[0].seq == 30
    assert late.lost == 30 and late.first_of_stream.seq == 30 and late.offer(frame(3, boot="b"), 2.2) == []
    assert late.counts == {"late": 1}
    # the worker stalled past resend_wait_s with the resend waiting in its channel: taken, it fills the gap
    stalled = FrameGate(ask_from_start=100)
    stalled.offer(frame(5), 0.0)
    assert stalled.ask() == (0, 4)
    out = [b.seq for s in range(5) for b in stalled.offer(frame(s), 3.0)]
    assert out == list(range(6)) and stalled.lost == 0
    # beyond ask_from_start (a counter that does not start at 0), or off: released at once
    assert [b.seq for b in FrameGate(ask_from_start=100).offer(frame(500), 0.0)] == [500]
    assert [b.seq for b in FrameGate().offer(frame(12), 0.0)] == [12]


# --------------------------------------------------------------------------------------
# The core: one track across streams and gaps
# --------------------------------------------------------------------------------------
CFG = default_incident()
KEY = wire.key(CFG.id, "ff1", "imu")


def run(core, frames_at, tick_every=1.0, fixes=(), admit=False):
    """Feed ``(frame, receive time)`` in order with a tick every ``tick_every`` s of receive time;
    ``fixes`` are ``(receive time, Fix)`` fed when their time comes; with ``admit`` each frame
    goes through the intake first, as in the service. Returns poses and every Status the ticks
    answered."""
    poses, statuses = [], []
    last_tick = -math.inf
    pending = sorted(fixes, key=lambda f: f[0])
    for f, rt in frames_at:
        while pending and pending[0][0] <= rt:
            frt, fix = pending.pop(0)
            poses += _poses(core.feed(Inbound("fix", wire.key(CFG.id, "ff1", "fix"), wire.encode(fix), frt)))
        payload = wire.encode(f)
        if not admit or core.admit("imu", KEY, len(payload), rt) is None:
            poses += _poses(core.feed(Inbound("imu", KEY, payload, rt)))
        if rt - last_tick >= tick_every:
            last_tick = rt
            statuses += [o.message for o in core.tick(rt) if isinstance(o.message, wire.Status)]
    return poses, statuses


def _poses(out):
    return [o.message for o in out if isinstance(o.message, wire.Pose)]


def at_rate(frames, rt0):
    return [(f, rt0 + k * PER_FRAME / RATE_HZ) for k, f in enumerate(frames)]


def test_a_restarted_wearable_continues_the_track_on_its_new_clock():
    w = walk(seconds=90.0, seed=3)
    core = IncidentCore(CFG)
    before, st1 = run(core, at_rate(w.frames[:400], 5000.0))
    steps_before = core.responders["ff1"].tracker.steps
    assert steps_before > 40
    # it restarts 10 s later: a new boot, seq from 0, its sensor clock from 5 s
    second = restamped(w.frames[500:], dt=5.0 - float(w.frames[500].t[0]), seq0=0, boot="b2")
    after, st2 = run(core, at_rate(second, 5000.0 + 50.0))
    r = core.responders["ff1"]
    steps = [p.steps for p in before + after]
    assert steps == sorted(steps) and r.tracker.steps > steps_before + 40  # the same count, going on
    jumps = [math.hypot(b.x - a.x, b.y - a.y) for a, b in zip(before + after, (before + after)[1:])]
    assert max(jumps) < 2.0  # no restart at the origin: the track goes on from where it was
    st = core.status_of(r, 5000.0 + 50.0 + 40.0)
    assert st.streams == 2 and st.boot == "b2" and st.gaps == 1 and st.gap_s == pytest.approx(10.1, abs=0.15)
    assert st.seq == len(second) - 1  # the acknowledgement is of the new stream
    assert after[-1].t == pytest.approx(float(second[-1].t[-1]), abs=1.0)  # poses on the wearable's new clock
    assert st.t == pytest.approx(float(second[-1].t[-1]), abs=1e-9)
    assert "man_down" not in {a for s in st1 + st2 for a in s.alarms}


def test_a_new_device_for_the_same_responder_continues_the_track():
    w = walk(seconds=60.0, seed=4)
    core = IncidentCore(CFG)
    run(core, at_rate(w.frames[:300], 100.0))
    steps = core.responders["ff1"].tracker.steps
    other = restamped(w.frames[320:], dt=123456.0, device="spare-phone", boot="x", seq0=7)
    run(core, at_rate(other, 100.0 + 32.0))
    r = core.responders["ff1"]
    assert r.tracker.steps > steps and r.gate.device == "spare-phone" and r.gate.streams == 2


def test_the_core_asks_for_a_gap_at_once_and_the_resent_frames_give_the_uninterrupted_track():
    w = walk(seconds=60.0, seed=7)
    frames = w.frames
    ref_poses, _ = run(IncidentCore(CFG), at_rate(frames, 100.0))
    core = IncidentCore(CFG)
    poses, _ = run(core, at_rate(frames[:200], 100.0))
    # frames 200..259 do not come (zenoh dropped them); the next ones do
    asked = [o.message for o in core.feed(Inbound("imu", KEY, wire.encode(frames[260]), 130.0))
             if isinstance(o.message, wire.Status)]
    assert [st.missing for st in asked] == [[frames[200].seq, frames[259].seq]]  # at once, not at the next tick
    assert core.status_of(core.responders["ff1"], 130.0).missing == [frames[200].seq, frames[259].seq]
    late = [(f, 130.1 + 0.01 * k) for k, f in enumerate(frames[261:270] + frames[200:260])]  # the resend, 0.1 s on
    more, _ = run(core, late + [(f, 131.0 + 0.1 * k) for k, f in enumerate(frames[270:])])
    r = core.responders["ff1"]
    assert r.gate.lost == 0 and r.gate.counts == {} and r.gate.missing is None
    got = [(p.t, p.steps, p.x, p.y) for p in poses + more]
    assert got == [(p.t, p.steps, p.x, p.y) for p in ref_poses]


def test_a_resend_queued_behind_a_worker_that_is_behind_still_fills_its_gap():
    """A worker 3 s behind its input takes every frame 3 s late, the wearable's resend too: it
    reaches the gate after the live frames that were queued before it, more than
    ``resend_wait_s`` (2 s) after the gap was asked for. The wait for an asked gap adds the
    responder's lag (how late its frames come in, :mod:`service.core.lag`), so the resend fills
    the gap: nothing lost, the track as if uninterrupted (before, the gap was declared lost 2 s
    after the ask, while the resend still waited in the worker's channel)."""
    w = walk(seconds=60.0, seed=7)
    frames = w.frames
    ref_poses, _ = run(IncidentCore(CFG), at_rate(frames, 100.0))
    behind = 3.0  # s: from frame 100 on the worker takes every frame this much later than it came
    core = IncidentCore(CFG)
    taken = [(f, rt + (behind if k >= 100 else 0.0)) for k, (f, rt) in enumerate(at_rate(frames, 100.0))]
    poses, _ = run(core, taken[:200])
    # frames 200..259 are dropped on the way; 260 is taken at 129 s and asks for them at once
    asked = [o.message for o in core.feed(Inbound("imu", KEY, wire.encode(frames[260]), taken[260][1]))
             if isinstance(o.message, wire.Status)]
    assert [st.missing for st in asked] == [[frames[200].seq, frames[259].seq]]
    ask_t = taken[260][1]
    # the resend leaves at once and waits behind `behind` s of frames in the worker's channel
    resend_t = ask_t + behind + 0.05
    live = [(f, rt) for f, rt in taken[261:] if rt < resend_t]
    resent = [(f, resend_t + 0.001 * k) for k, f in enumerate(frames[200:260])]
    rest = [(f, rt) for f, rt in taken[261:] if rt >= resend_t]
    assert resend_t - ask_t > 2.0 and live and live[-1][1] - ask_t > 2.0  # past resend_wait_s: the old verdict
    more, _ = run(core, live + resent + rest)
    r = core.responders["ff1"]
    assert r.gate.lost == 0 and r.gate.counts == {} and r.gate.missing is None, (r.gate.lost, list(r.gate.events)[-3:])
    got = [(p.t, p.steps, p.x, p.y) for p in poses + more]
    assert got == [(p.t, p.steps, p.x, p.y) for p in ref_poses]


def test_an_outage_is_counted_in_frames_and_seconds_and_raises_no_man_down():
    w = walk(seconds=120.0, seed=5)
    core = IncidentCore(CFG)
    kept = [(f, 7000.0 + k * 0.1) for k, f in enumerate(w.frames) if not 500 <= k < 900]  # 40 s never arrive
    poses, statuses = run(core, kept)
    st = core.status_of(core.responders["ff1"], kept[-1][1])
    assert st.lost == 400 and st.gaps == 1 and st.gap_s == pytest.approx(40.0, abs=0.02)
    assert not any("man_down" in s.alarms for s in statuses)
    assert core.counters.errors == 0


def test_stillness_across_an_outage_is_no_man_down_until_seen_for_the_no_motion_time():
    settings = WalkerSettings(rate_hz=RATE_HZ)
    w = SimulatedWalker("ff1", None, settings, 6, start_t=0.0, floors=(0, 0), attitude=False)
    w.stand_still(math.inf, at=30.0)  # stops at 30 s for good: still, upright, only sensor noise
    b = w.next_batch(int(150 * RATE_HZ))
    frames = list(wire.imu_batches_from_arrays("ff1", "p", b.t, b.acc, b.gyr, b.mag, b.pressure_t, b.pressure,
                                               carry="handheld", per_batch=PER_FRAME, boot="b"))
    # frames 35 s .. 75 s are lost: the stillness before the outage is not seen through it
    kept = [(f, 100.0 + k * 0.1) for k, f in enumerate(frames) if not 350 <= k < 750]
    core = IncidentCore(CFG)
    _, statuses = run(core, kept)
    down = [s.last_heard - 100.0 for s in statuses if "man_down" in s.alarms]
    # only after 30 s of stillness seen in frames after the outage (75 s + 30 s), not at 60 s
    assert down and min(down) >= 105.0 - 0.5
    # without the outage the same stillness raises it 30 s after it began (the reference)
    core2 = IncidentCore(CFG)
    _, st2 = run(core2, [(f, 100.0 + k * 0.1) for k, f in enumerate(frames)])
    down2 = [s.last_heard - 100.0 for s in st2 if "man_down" in s.alarms]
    assert down2 and min(down2) < 70.0


def _gnss_at(core, x, y, t, accuracy=3.0):
    lat, lon, _ = core.incident.to_geodetic(x, y)
    return wire.Fix.gnss("ff1", t, lat=float(lat), lon=float(lon), accuracy=accuracy)


@pytest.mark.parametrize("gap_reanchor_s", [2.0, math.inf])
def test_a_fix_after_a_gap_re_anchors_the_track(gap_reanchor_s):
    """After 40 s without frames the walker can be anywhere within a brisk walk: a GNSS fix 25 m
    from the dead-reckoned position is taken (and moves the track) when the gap widens the
    position, and gated away as an outlier when gaps are ignored (the control)."""
    w = walk(seconds=110.0, seed=7)
    core = IncidentCore(CFG, CoreSettings(gap_reanchor_s=gap_reanchor_s))
    start = wire.Fix.checkpoint("ff1", float(w.t[0]), x=float(w.x[0]), y=float(w.y[0]), floor=0, sigma=0.3)
    kept = [(f, 100.0 + k * 0.1) for k, f in enumerate(w.frames) if not 400 <= k < 800]
    head, tail = kept[:450], kept[450:]  # 5 s of walking after the gap, then the fix
    poses, _ = run(core, head, fixes=[(99.0, start)])
    last = poses[-1]
    fix = _gnss_at(core, last.x + 25.0, last.y, last.t)
    out = _poses(core.feed(Inbound("fix", wire.key(CFG.id, "ff1", "fix"), wire.encode(fix), head[-1][1] + 0.01)))
    tr = core.responders["ff1"].tracker
    if math.isfinite(gap_reanchor_s):
        assert last.cov[0, 0] > 1000.0  # the gap: the position is anyone's guess within a brisk walk
        assert tr.fix_rejects == {} and out and out[-1].cov[0, 0] < 20.0  # taken: the fix anchors it again
        sm = core.track("ff1")["track"]  # the graph's estimate (the published pose closes in step by step)
        assert math.hypot(sm["x"][-1] - (last.x + 25.0), sm["y"][-1] - last.y) < 3.0
    else:
        # held out: by the walk gate (dead reckoning since the start fix) before the graph's own GNSS gate
        assert tr.fix_rejects.get("walk_gate", 0) + tr.fix_rejects.get("gnss_gate", 0) == 1 and not out
    run(core, tail)
    assert core.counters.errors == 0


def test_device_time_fixes_follow_the_stream_clock():
    """A checkpoint stamped on the new stream's device clock lands at that moment of the track."""
    w = walk(seconds=70.0, seed=8)
    core = IncidentCore(CFG)
    run(core, at_rate(w.frames[:300], 10.0))
    second = restamped(w.frames[320:], dt=-float(w.frames[320].t[0]), seq0=0, boot="b2")  # clock from 0
    run(core, at_rate(second[:200], 10.0 + 32.0))
    r = core.responders["ff1"]
    now_device = float(second[199].t[-1])
    cp = wire.Fix.checkpoint("ff1", now_device - 0.5, x=3.0, y=4.0, floor=0, sigma=0.3)
    out = _poses(core.feed(Inbound("fix", wire.key(CFG.id, "ff1", "fix"), wire.encode(cp), 10.0 + 32.0 + 20.0)))
    # taken at once (on the track's clock it is 0.5 s old; read as track time it would be ~1000 s old)
    assert r.fixes_rejected == {} and r.tracker.fix_rejects == {} and r.tracker.fixes_queued == 0
    assert out and math.hypot(out[-1].x - 3.0, out[-1].y - 4.0) < 1.5


def test_a_burst_of_fresh_streams_cannot_take_the_track_over_in_the_core():
    """Issue 32, attack 6 in the core: a 5 s burst (30 frames/s) with fresh boot ids on the
    responder's key while the real wearable walks: every real frame is taken, the poses are
    those of a run without the burst, the burst is counted (``other_stream``) and alarmed
    (``stream_contested``) and the intake does not throttle the real frames."""
    w = walk(seconds=40.0, seed=5)
    frames_at = at_rate(w.frames, 7000.0)
    clean, _ = run(IncidentCore(CFG), frames_at)
    core = IncidentCore(CFG)
    fake = restamped(w.frames[:150], dt=-3.0, seq0=0, boot="forged")
    mixed = list(frames_at)
    for j, f in enumerate(fake):  # 150 frames in 5 s, from 10 s on, two boots in turn
        g = f.model_copy(update={"boot": f"forged{j % 2}"})
        mixed.append((g, 7010.0 + j / 30.0 + 0.003))
    mixed.sort(key=lambda e: e[1])
    poses, statuses = run(core, mixed, admit=True)
    r = core.responders["ff1"]
    st = core.status_of(r, 7040.0)
    assert r.gate.accepted == len(w.frames) and st.streams == 1 and st.rejected.get("other_stream") == 150
    assert "throttled" not in st.rejected and r.gate.contested == 150
    assert [(p.x, p.y) for p in poses] == [(p.x, p.y) for p in clean]
    assert any("stream_contested" in s.alarms for s in statuses)
    assert "stream_contested" not in core.status_of(r, 7040.0 + 20.0).alarms

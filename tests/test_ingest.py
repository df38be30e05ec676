"""The per-responder frame gate (service.core.gate.FrameGate): ordering, loss, rejects, restarts."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.core.gate import GATE_REASONS, FrameGate
from service.protocol.wire import ImuBatch

N = 5  # samples per frame
DT = 0.01  # s between samples
FRAME_S = N * DT


def frame(seq: int, device: str = "phone-A", t0: float | None = None) -> ImuBatch:
    """Frame ``seq`` of a continuous 100 Hz stream (times follow from the seq unless given)."""
    start = seq * FRAME_S if t0 is None else t0
    t = start + np.arange(N) * DT
    z = np.zeros((N, 3))
    return ImuBatch(responder="ff1", device=device, seq=seq, t=t, acc=z, gyr=z)


def offer_all(gate: FrameGate, seqs, start=0.0, step=0.01) -> list[int]:
    out = []
    for i, s in enumerate(seqs):
        out += [b.seq for b in gate.offer(frame(s), start + i * step)]
    return out


def balanced(gate: FrameGate) -> bool:
    return gate.accepted + gate.rejected + gate.held == gate.offered


# --------------------------------------------------------------------------------------
# Properties
# --------------------------------------------------------------------------------------
@st.composite
def window_permutations(draw, window_max=6):
    """A permutation of 0..n-1 where no frame is overtaken by more than ``window`` others:
    frame i arrives in the order of ``i + d_i`` with ``0 <= d_i <= window``, ties to the higher
    seq, so a frame can be overtaken by exactly ``window`` others (the worst case allowed)."""
    window = draw(st.integers(0, window_max))
    n = draw(st.integers(1, 60))
    delay = draw(st.lists(st.integers(0, window), min_size=n, max_size=n))
    order = sorted(range(n), key=lambda i: (i + delay[i], -i))
    return window, order


@settings(max_examples=300)
@given(window_permutations())
def test_any_permutation_within_the_window_is_released_in_order_exactly_once(case):
    window, order = case
    gate = FrameGate(reorder_window=window)
    released = offer_all(gate, order)
    released += [b.seq for b in gate.flush()]
    # the first frame to arrive opens the stream, so only frames from it on can be released
    assert released == list(range(order[0], len(order)))
    assert gate.lost == 0 and gate.gaps == 0 and gate.rejected == (order[0] and sum(s < order[0] for s in order))
    assert balanced(gate)


def overtaken_by(arrivals: list[int]) -> dict[int, int]:
    """For each distinct seq, how many distinct higher seqs arrived before its first arrival."""
    seen: set[int] = set()
    count = {}
    for s in arrivals:
        if s not in count:
            count[s] = sum(1 for x in seen if x > s)
        seen.add(s)
    return count


@settings(max_examples=400)
@given(st.integers(0, 5), st.lists(st.integers(0, 30), min_size=1, max_size=80))
def test_arbitrary_arrivals_release_in_order_once_and_counts_add_up(window, arrivals):
    gate = FrameGate(reorder_window=window)
    released = []
    for i, s in enumerate(arrivals):
        released += [b.seq for b in gate.offer(frame(s), i * 0.01)]
        assert balanced(gate)
    released += [b.seq for b in gate.flush()]
    assert released == sorted(set(released))  # in order, never twice
    first = arrivals[0]
    expected = {s for s, k in overtaken_by(arrivals).items() if s >= first and k <= window}
    assert set(released) == expected  # released iff overtaken by at most `window` frames
    assert gate.held == 0 and gate.accepted == len(released)
    assert gate.accepted + gate.rejected == gate.offered == len(arrivals)
    assert sum(gate.counts.values()) == gate.rejected


@settings(max_examples=200)
@given(st.lists(st.integers(0, 20), min_size=1, max_size=60), st.integers(0, 4))
def test_duplicates_are_never_released_twice(seqs, window):
    arrivals = [s for s in seqs for _ in range(2)]  # every frame arrives twice
    gate = FrameGate(reorder_window=window)
    released = offer_all(gate, arrivals) + [b.seq for b in gate.flush()]
    assert len(released) == len(set(released))
    assert gate.counts["duplicate"] >= gate.accepted  # each released frame's twin was turned away
    assert gate.accepted + gate.rejected == gate.offered


# --------------------------------------------------------------------------------------
# Behaviour, case by case
# --------------------------------------------------------------------------------------
def test_in_order_stream_passes_straight_through():
    gate = FrameGate()
    assert offer_all(gate, range(10)) == list(range(10))
    assert gate.accepted == 10 and gate.counts == {} and gate.gaps == 0 and gate.last_heard == pytest.approx(0.09)
    assert gate.last_t == pytest.approx(9 * FRAME_S + (N - 1) * DT)


def test_a_swapped_pair_waits_for_the_missing_frame():
    gate = FrameGate(reorder_window=4)
    assert offer_all(gate, [0, 2]) == [0]
    assert gate.held == 1
    assert [b.seq for b in gate.offer(frame(1), 0.05)] == [1, 2]
    assert gate.held == 0 and gate.lost == 0


def test_a_lost_frame_is_declared_after_the_window_fills():
    gate = FrameGate(reorder_window=3)
    assert offer_all(gate, [0, 2, 3, 4]) == [0]  # 3 held: still waiting for 1
    assert [b.seq for b in gate.offer(frame(5), 0.1)] == [2, 3, 4, 5]  # 4 held > 3: 1 is lost
    assert gate.lost == 1 and gate.gaps == 1
    assert any(r == "lost" and "seq 1 lost" in d for _, r, d in gate.events)
    assert gate.offer(frame(1), 0.2) == []  # the lost frame turning up after all
    assert gate.counts == {"late": 1}
    assert "declared lost" in gate.events[-1][2]
    assert balanced(gate)


def test_a_run_of_lost_frames_is_one_gap():
    gate = FrameGate(reorder_window=0)
    assert offer_all(gate, [0, 5]) == [0, 5]
    assert gate.lost == 4 and gate.gaps == 1
    assert gate.events[-1][1] == "lost" and "seq 1..4 (4 frames) lost" in gate.events[-1][2]


def test_duplicates_of_released_and_of_held_frames():
    gate = FrameGate()
    offer_all(gate, [0, 1, 3])
    assert gate.offer(frame(1), 1.0) == []
    assert gate.offer(frame(3), 1.0) == []
    assert gate.counts == {"duplicate": 2}
    details = [d for _, r, d in gate.events if r == "duplicate"]
    assert "already released" in details[0] and "already waiting" in details[1]


def test_frames_older_than_the_first_are_late():
    gate = FrameGate()
    offer_all(gate, [5, 6])
    assert gate.offer(frame(2), 0.1) == []
    assert gate.counts == {"late": 1} and "precedes the first frame" in gate.events[-1][2]


def test_time_going_back_or_repeating_is_rejected():
    gate = FrameGate()
    gate.offer(frame(0), 0.0)
    last = float(frame(0).t[-1])
    assert gate.offer(frame(1, t0=last), 0.01) == []  # repeats the last released sample's time
    assert gate.offer(frame(2, t0=last - 1.0), 0.02) == []  # goes back
    assert gate.counts == {"time_order": 2}
    assert "not after the last released sample" in gate.events[-1][2]
    assert [b.seq for b in gate.offer(frame(3), 0.03)] == [3]  # the stream carries on
    assert balanced(gate)


def test_a_held_frame_that_overlaps_its_predecessor_is_rejected_on_release():
    gate = FrameGate()
    gate.offer(frame(0), 0.0)
    gate.offer(frame(2, t0=float(frame(1).t[2])), 0.01)  # starts inside frame 1's span
    assert [b.seq for b in gate.offer(frame(1), 0.02)] == [1]
    assert gate.counts == {"time_order": 1} and gate.held == 0 and balanced(gate)


def test_a_device_time_gap_is_counted_and_the_frame_released():
    gate = FrameGate(max_gap_s=0.5)
    gate.offer(frame(0), 0.0)
    out = gate.offer(frame(1, t0=float(frame(0).t[-1]) + 2.0), 0.01)
    assert [b.seq for b in out] == [1]
    assert gate.gaps == 1 and gate.lost == 0
    assert gate.events[-1][1] == "gap" and "2.000 s of device time" in gate.events[-1][2]
    gate.offer(frame(2, t0=float(out[0].t[-1]) + 0.4), 0.02)  # below max_gap_s
    assert gate.gaps == 1


def test_held_frames_expire_after_max_hold():
    gate = FrameGate(reorder_window=4, max_hold_s=0.5)
    offer_all(gate, [0, 2, 3])
    assert gate.expire(0.3) == []
    assert [b.seq for b in gate.expire(0.6)] == [2, 3]
    assert gate.lost == 1 and gate.events[-1][1] == "lost" and "not received within 0.5 s" in gate.events[-1][2]
    gate2 = FrameGate(reorder_window=4, max_hold_s=0.5)
    offer_all(gate2, [0, 2])
    assert [b.seq for b in gate2.offer(frame(3), 2.0)] == [2, 3]  # offer() expires first


def test_flush_releases_everything_held_in_order():
    gate = FrameGate(reorder_window=10)
    offer_all(gate, [0, 4, 2, 7])
    assert [b.seq for b in gate.flush()] == [2, 4, 7]
    assert gate.held == 0 and gate.lost == 4 and gate.gaps == 3 and balanced(gate)  # 1, 3, 5..6


def test_a_new_device_starts_a_new_stream():
    gate = FrameGate(takeover_after_s=0.5)
    offer_all(gate, [0, 1, 2, 4])
    # while phone-A is live, phone-B's frames on its key have not proven themselves: held as the
    # candidate stream (not taken, not yet counted against anyone)
    assert gate.offer(frame(0, device="phone-B"), 0.1) == [] and gate.counts == {}
    out = gate.offer(frame(0, device="phone-B"), 0.6)  # phone-A quiet for 0.5 s: B takes over
    assert [(b.device, b.seq) for b in out] == [("phone-A", 4), ("phone-B", 0)]
    assert gate.epoch == 1 and any(r == "restart" and "phone-B" in d for _, r, d in gate.events)
    assert [b.seq for b in gate.offer(frame(1, device="phone-B"), 0.7)] == [1]


def test_a_rebooted_wearable_after_silence_is_a_new_stream():
    gate = FrameGate(restart_after_s=30.0)
    offer_all(gate, range(50))
    assert gate.offer(frame(0), 5.0) == []  # shortly after: a duplicate
    assert gate.counts == {"duplicate": 1}
    out = gate.offer(frame(0), 60.0)  # a minute of silence, then seq 0 again: it restarted
    assert [b.seq for b in out] == [0] and gate.epoch == 1
    assert [b.seq for b in gate.offer(frame(1), 60.1)] == [1]
    assert balanced(gate)


def test_silence_alone_does_not_restart_a_healthy_stream():
    gate = FrameGate(restart_after_s=30.0)
    offer_all(gate, range(3))
    assert [b.seq for b in gate.offer(frame(3), 100.0)] == [3]
    assert gate.epoch == 0


def test_decode_rejects_are_counted_beside_the_gates_own():
    gate = FrameGate()
    gate.offer(frame(0), 1.0)
    gate.count("nonfinite", "imu: acc: nan at index [3, 0]", receive_time=2.0)
    assert gate.counts == {"nonfinite": 1} and gate.rejected == 0 and gate.last_heard == 2.0
    assert gate.events[-1] == (2.0, "nonfinite", "imu: acc: nan at index [3, 0]")
    assert balanced(gate)


def test_events_are_bounded():
    gate = FrameGate(max_events=5)
    gate.offer(frame(0), 0.0)
    for i in range(20):
        gate.offer(frame(0), 0.1 + i * 0.01)
    assert len(gate.events) == 5 and gate.counts["duplicate"] == 20


def test_settings_are_checked():
    with pytest.raises(ValueError):
        FrameGate(reorder_window=-1)
    with pytest.raises(ValueError):
        FrameGate(max_gap_s=0)
    assert set(GATE_REASONS) == {"duplicate", "late", "time_order", "old_stream", "other_stream", "seq_jump"}

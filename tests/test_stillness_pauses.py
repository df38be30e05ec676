"""A still phone whose sensor feed pauses (a throttled or busy browser, a hiccup of the sensor
service) reaches no motion, and man-down, when it would without the pauses; a real movement
still starts the stillness again; a gap longer than ``motionless_pause_s`` is not stillness
(:func:`pdr.fleet_kernels.motion_windows`, :mod:`service.core.alarms`).

Tolerance: the motion state is decided on a grid of ``state_grid_s`` (0.5 s), and the pauses
remove samples, so the stillness may be seen to start up to a sample later; both are asserted
within one grid step."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pdr.events import MotionEvent, MotionState
from pdr.pipeline import PdrPipeline, PipelineSettings, frames_of, run_pipeline
from pdr.simulation import SimulatedWalker, WalkerSettings
from pdr.synthetic import static_imu
from service.core.incident_core import Inbound, IncidentCore
from service.protocol import wire
from tests.test_man_down_prompt import CFG, KEY, STOP_S, _down, _first
from tests.walkers import PER_FRAME, RATE_HZ

SETTINGS = PipelineSettings()
GRID = SETTINGS.state_grid_s
PHONE_HZ = 60.0  # a browser's motion sensor rate


def _pauses(t: np.ndarray, start: float, end: float, every: float = 3.0) -> np.ndarray:
    """A mask keeping ``t`` but for a pause every ``every`` s from ``start``, of 0.2-0.9 s
    (a different length each time)."""
    keep = np.ones(t.size, bool)
    for k, s in enumerate(np.arange(start, end, every)):
        keep &= ~((t > s) & (t < s + 0.2 + 0.1 * (k * 3 % 8)))
    return keep


def _no_motion(t, acc, gyr) -> MotionEvent:
    events = run_pipeline(PdrPipeline(SETTINGS), frames_of(t, acc, gyr, None, per_frame=6))
    return next(e for e in events if isinstance(e, MotionEvent) and e.state is MotionState.NO_MOTION)


@pytest.fixture(scope="module")
def lying():
    return static_imu(60.0, PHONE_HZ, seed=3)


def test_a_still_phone_with_sensor_pauses_reaches_no_motion_when_it_would_without(lying):
    keep = _pauses(lying.t, 2.0, 58.0)
    gaps = np.diff(lying.t[keep])
    assert 0.2 <= gaps.max() - 1 / PHONE_HZ and gaps.max() < 0.95 and (gaps > 0.15).sum() >= 15
    ref, paused = _no_motion(lying.t, lying.acc, lying.gyr), _no_motion(lying.t[keep], lying.acc[keep], lying.gyr[keep])
    assert ref.t == pytest.approx(SETTINGS.no_motion_after_s + 1.0, abs=2 * GRID)  # after the first full window
    assert paused.t == pytest.approx(ref.t, abs=GRID) and paused.since == pytest.approx(ref.since, abs=GRID)


def test_a_movement_during_the_stillness_starts_it_again_even_right_after_a_pause(lying):
    keep = _pauses(lying.t, 2.0, 58.0)
    after_pause = lying.t[keep][np.searchsorted(lying.t[keep], 14.0, side="right")]  # the pause from 14 s ends
    assert after_pause > 14.2
    for at in (12.5, after_pause):  # after_pause: the first samples after a pause (few, their windows short)
        gyr = lying.gyr.copy()
        turn = (lying.t >= at) & (lying.t < at + 0.3)  # a third of a second turning the phone
        gyr[turn, 2] += 1.0
        ev = _no_motion(lying.t[keep], lying.acc[keep], gyr[keep])
        moved = lying.t[keep & turn][-1]
        # the stillness begins once no window holds the turn: its last sample + a window, or the
        # last sample before a pause within that
        assert moved <= ev.since <= moved + SETTINGS.motionless_window_s
        assert ev.t >= moved + SETTINGS.no_motion_after_s


def test_a_gap_longer_than_the_bound_is_not_stillness(lying):
    gap = (15.0, 15.0 + SETTINGS.motionless_pause_s + 1.0)
    keep = (lying.t <= gap[0]) | (lying.t >= gap[1])
    ev = _no_motion(lying.t[keep], lying.acc[keep], lying.gyr[keep])
    after = lying.t[keep][lying.t[keep] >= gap[1]][0]
    assert ev.since >= after  # counted from the gap's end, not from the start
    assert ev.since == pytest.approx(after + SETTINGS.motionless_window_s, abs=GRID)  # once a window is full again


def test_a_stream_too_sparse_to_fill_a_window_never_proves_stillness():
    """Bursts of 0.1 s every 2 s (each pause within the bound) fill no window: the stillness
    clock restarts as after a gap, and no motion is never reached."""
    imu = static_imu(80.0, PHONE_HZ, seed=4)
    keep = (imu.t % 2.0) < 0.1
    events = run_pipeline(PdrPipeline(SETTINGS), frames_of(imu.t[keep], imu.acc[keep], imu.gyr[keep], None, per_frame=6))
    assert not any(isinstance(e, MotionEvent) and e.state is MotionState.NO_MOTION for e in events)


# ------------------------------------------------------------------ through the service core


def _walker_frames(keep_fn) -> list[wire.ImuBatch]:
    w = SimulatedWalker("ff1", None, WalkerSettings(rate_hz=RATE_HZ), 6, start_t=0.0, floors=(0, 0), attitude=False)
    w.stand_still(math.inf, at=STOP_S)
    b = w.next_batch(int(90.0 * RATE_HZ))
    keep = keep_fn(b.t)
    return list(wire.imu_batches_from_arrays("ff1", "p", b.t[keep], b.acc[keep], b.gyr[keep], b.mag[keep], b.pressure_t,
                                             b.pressure, carry="handheld", per_batch=PER_FRAME, boot="b"))


def _statuses(frames) -> list[wire.Status]:
    """The frames at the pace of their device time (receive time follows it), a Status a second."""
    core, out, next_tick = IncidentCore(CFG), [], 0.0
    for f in frames:
        rt = 100.0 + float(f.t[-1])
        core.feed(Inbound("imu", KEY, wire.encode(f), rt))
        if rt >= next_tick:
            next_tick = rt + 1.0
            out += [o.message for o in core.tick(rt) if isinstance(o.message, wire.Status)]
    return out


@pytest.fixture(scope="module")
def reference_down():
    return _first(_statuses(_walker_frames(lambda t: np.ones(t.size, bool))), _down)


def test_man_down_with_sensor_pauses_is_raised_when_it_is_without(reference_down):
    down = _first(_statuses(_walker_frames(lambda t: _pauses(t, STOP_S + 1.0, 90.0))), _down)
    assert reference_down is not None and down is not None
    assert down.man_down_at == pytest.approx(reference_down.man_down_at, abs=GRID)
    assert down.t == pytest.approx(reference_down.t, abs=1.0 + GRID)  # a Status a second


@pytest.mark.parametrize("start", [STOP_S + 10.0, STOP_S + 10.05])  # between frames; within one (the PDR's rule)
def test_man_down_after_a_long_gap_counts_from_its_end(reference_down, start):
    gap = (start, start + 3.0)  # longer than motionless_pause_s and the service's gap_reanchor_s
    statuses = _statuses(_walker_frames(lambda t: (t < gap[0]) | (t >= gap[1])))
    down = _first(statuses, _down)
    assert down is not None and down.t >= down.man_down_at  # raised when due, not before
    assert down.man_down_at >= gap[1] + SETTINGS.no_motion_after_s + SETTINGS.state_delay_s - 1e-6
    assert down.man_down_at > reference_down.man_down_at + 2.0

"""One responder's state inside the incident core, and how its frames are joined for the tracker."""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from pdr.pipeline import ImuFrame
from service.core.gate import FrameGate
from service.core.lag import FrameLag
from service.core.tracker import ResponderTracker
from service.protocol import wire

# a Responder's last_status when its Status is owed at the next tick, outside the idle budget (a new
# responder; an order, an acknowledgement or an "I'm OK" since its last Status: service.core.status_reporter)
STATUS_OWED = -math.inf


@dataclass
class Responder:
    """What the core keeps per responder: the frame gate, the tracker and the counters that
    ``Status`` reports. Nothing here touches the network or a clock."""

    id: str
    gate: FrameGate
    tracker: ResponderTracker
    first_heard: float  # service time of the first message
    seq: int = -1  # seq of the newest frame the tracker has seen
    seq_oldest: int = -1  # seq of the oldest frame in the tracker's latest batch
    backlog: list = field(default_factory=list)  # released frames waiting for the tracker (one round)
    epoch: int = 0  # the gate's stream epoch the tracker belongs to
    poses: int = 0
    rejects: deque = field(default_factory=lambda: deque(maxlen=1024))  # service times of rejects
    fixes_rejected: dict = field(default_factory=dict)
    present: bool | None = None  # liveliness: None unknown, True token alive, False token gone
    utc_offset: float | None = None  # s, UTC minus the device clock, as the wearable last said
    t_offset: float = 0.0  # s, the track's clock minus the current stream's device clock (0 for the first stream)
    last_t: float = math.nan  # s, track clock: the newest sample the tracker has been given
    last_rt: float | None = None  # service time the newest frame was released at
    stream_start: object = None  # the gate's first frame of the stream the tracker follows now
    gap_end: float = -math.inf  # s, track clock: the first sample after the latest gap
    last_input: float = -math.inf  # service time of the newest message of any kind (expiry)
    last_status: float = STATUS_OWED  # service time of the newest Status answered (STATUS_OWED: due at the next tick)
    last_alarms: list = field(default_factory=list)  # the alarms it carried
    alarm_since: dict = field(default_factory=dict)  # alarm -> the service time it began (as ticks saw it)
    commands: dict = field(default_factory=dict)
    ok_at: float = -math.inf  # s, track clock: the wearer's latest answer "I'm OK" to the man-down prompt
    early_acks: dict = field(default_factory=dict)  # (action, id) -> ack time, for an order not yet arrived  # action -> the newest order: id, issued_at, issued_by, acked_at
    logged: deque = field(default_factory=lambda: deque(maxlen=64))
    last_checkpoint: object | None = None  # service.core.plausibility.Reference of the last checkpoint fix taken
    fixes_flagged: int = 0  # checkpoint fixes taken but flagged as implausible jumps
    beacons_heard: dict = field(default_factory=dict)  # beacon id -> device time (s) of the newest scan that heard it
    fix_senders: dict = field(default_factory=dict)  # (source, t) -> who sent a fix the tracker holds (fix_audit)
    last_fix_refused: float = -math.inf  # service time of the newest fix refused for it (the fixes_refused alarm)
    lag: FrameLag = field(default_factory=FrameLag)  # how late its frames reach the core (service.core.lag)

    def taken_late_s(self) -> float:
        """s: how much later than its quickest its newest released frame was taken (its lag
        then, :mod:`service.core.lag`); a resend it asks for queues about that long too
        (:meth:`service.core.gate.FrameGate.expire`). 0 before any frame."""
        return self.lag.at(self.last_rt) if self.last_rt is not None else 0.0


@dataclass
class Newcomer:
    """An id the intake admitted none of whose messages has decoded yet: what the core keeps
    for it instead of a :class:`Responder` (no gate, tracker, fleet slot or Status). Its
    rejects move into the responder its first decodable message makes (issue 20: a flood of
    garbage on fresh ids costs a few numbers per id, not a tracker each)."""

    first_heard: float  # service time of its first message
    last_input: float  # service time of its newest
    rejects: deque = field(default_factory=lambda: deque(maxlen=64))  # service times (the burst alarm, later)
    frames: dict = field(default_factory=dict)  # frame rejects by reason
    fixes: dict = field(default_factory=dict)  # fix rejects by reason


def continues(prev: wire.ImuBatch, b: wire.ImuBatch) -> bool:
    """Can ``b`` join ``prev`` in one pipeline batch: later samples, the same sensors."""
    return (prev.mag is None) == (b.mag is None) and len(b.t) > 0 and len(prev.t) > 0 and b.t[0] > prev.t[-1]


def frame_of(batches: list[wire.ImuBatch], offset: float = 0.0) -> ImuFrame:
    """One pipeline frame of consecutive wire frames (see :func:`continues`); ``offset`` (s) is
    added to every time (the track's clock for a stream whose device clock differs)."""
    if offset:
        return _shifted(frame_of(batches), offset)
    if len(batches) == 1:
        b = batches[0]
        return ImuFrame(b.t, b.acc, b.gyr, b.mag, b.pressure_t, b.pressure)

    def cat(name):
        parts = [getattr(b, name) for b in batches if getattr(b, name) is not None]
        return np.concatenate(parts) if parts else None

    pt = [b.pressure_t for b in batches if b.pressure_t is not None and b.pressure is not None]
    pv = [b.pressure for b in batches if b.pressure_t is not None and b.pressure is not None]
    return ImuFrame(cat("t"), cat("acc"), cat("gyr"), cat("mag"),
                    np.concatenate(pt) if pt else None, np.concatenate(pv) if pv else None)


def _shifted(f: ImuFrame, offset: float) -> ImuFrame:
    return ImuFrame(f.t + offset, f.acc, f.gyr, f.mag, None if f.pressure_t is None else f.pressure_t + offset,
                    f.pressure)

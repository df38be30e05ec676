"""The core's vocabulary: what goes in (:class:`Inbound`), what comes out (:class:`Outbound`),
its settings (every number with its unit) and its counters."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

from service.core.intake import IntakeSettings
from service.core.plausibility import PlausibilitySettings
from service.core.tracker import TrackerSettings
from service.protocol import wire

INBOUND_KINDS = ("imu", "fix", "presence", "command", "ack", "op", "access")
MAX_EARLY_ACKS = 8  # acknowledgements kept per responder while their order has not arrived


class Inbound(NamedTuple):
    """A message as the shell took it: ``received`` is the service's wall clock (unix s) then;
    ``parts`` its key as the shell read it at its edge (:func:`service.protocol.keys.read_key`:
    the parts, or why the key is not one), which the intake and the core take without reading
    the key again. None: nobody read it yet (a recording replayed, a test), the core reads it."""

    kind: str
    key: str
    payload: bytes
    received: float
    parts: wire.KeyParts | ValueError | None = None


class Outbound(NamedTuple):
    """A message the core answers with: the shell encodes and publishes it on ``key``."""

    key: str
    message: wire.WireMessage


@dataclass(frozen=True)
class CoreSettings:
    tracker: TrackerSettings | None = None  # None: tracker_settings_for(the incident)
    lost_contact_s: float = wire.LOST_CONTACT_S  # s without a frame -> lost-contact alarm
    rejected_window_s: float = 10.0  # s
    rejected_burst: int = 5  # rejects within the window -> alarm
    reorder_window: int = 4  # frames a late frame may be overtaken by
    ask_from_start: int = 3000  # frames: a stream first heard at seq s in 1..this has [0, s-1] asked for (the
    # wearable's keep; a subscriber declared after the wearable began may lose its first frames: gate.py)
    entry_sigma_m: float | None = 50.0  # m: responders not yet placed by a checkpoint start at the origin
    # with this σ at their first step (None: no pose until a checkpoint places them)
    log_rejects_per_window: int = 3  # full log lines per source and window; all are counted
    log_lines_per_window: int = 40  # full log lines per window over all sources (then summaries)
    max_coalesce: int = 50  # frames of one responder run through its tracker as one batch, at most
    command_answer_s: float = 30.0  # s a roll call or evacuation order may go unanswered before it alarms
    fix_future_s: float = 2.0  # s: a fix this far ahead of the newest sample is from the future (a wrong clock)
    intake: IntakeSettings = field(default_factory=IntakeSettings)  # budgets and admission (service/core/intake.py)
    expire_after_s: float = 1800.0  # s of silence after which a responder leaves the core (its track stays recorded)
    expire_unplaced_s: float = 120.0  # s of silence after which an id that never had a frame released leaves
    gap_reanchor_s: float = 2.0  # s: a gap in the frames longer than this widens the position for the next fix
    gap_speed_mps: float = 1.5  # m/s: the walk a gap may hide (a brisk pace), as position sigma per second
    same_clock_tolerance_s: float = 5.0  # s: a new stream whose first sample is within the receive gap + this
    # of the old stream's last is on the same device clock (the track's times stay the device's)
    min_stream_gap_s: float = 0.01  # s between a stream's last sample and the next stream's first, at least
    max_clock_lead_s: float = 60.0  # s a device clock may run ahead of the service's across a gap (beyond: a leap)
    idle_after_s: float = 2.0  # s without a message after which a responder's Status goes out less often ...
    idle_status_every_s: float = 5.0  # ... every this many s (and at once when its alarms change)
    plausibility: PlausibilitySettings = field(default_factory=PlausibilitySettings)


@dataclass
class CoreCounters:
    frames_processed: int = 0
    tracker_batches: int = 0  # tracker calls: frames_processed / tracker_batches frames each on average
    errors: int = 0  # exceptions caught while processing (logged a few times per window)
    received: dict = field(default_factory=lambda: {"imu": 0, "fix": 0, "op": 0})  # payloads taken, good or bad
    expired: int = 0  # responders that left after their silence
    newcomers_forgotten: int = 0  # admitted ids that never sent a decodable message, forgotten after their silence


@dataclass
class CoreClock:
    """The core's time, which its parts share: the ``received`` time of the message in hand, or
    the time of the latest tick (the core has no clock of its own)."""

    now: float = 0.0

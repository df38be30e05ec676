"""The man-down pre-alarm and the wearer's answer (issue 28): a still responder's Status says
when man-down will be raised (``man_down_at``) from PROMPT_BEFORE_S before it; an answer
"I'm OK" (an Ack with action ok, on the device clock) starts the no-motion clock again; no
answer, and man-down is raised at that time."""
from __future__ import annotations

import functools
import math

import pydantic
import pytest

from pdr.simulation import SimulatedWalker, WalkerSettings
from service.core.alarms import PROMPT_BEFORE_S
from service.core.incident_core import Inbound, IncidentCore
from service.core.tracker import tracker_settings_for
from service.protocol import wire
from service.protocol.incident import default_incident
from tests.walkers import PER_FRAME, RATE_HZ

CFG = default_incident()
KEY = wire.key(CFG.id, "ff1", "imu")
ACK_KEY = wire.key(CFG.id, "ff1", "ack")
STOP_S = 20.0  # the walker stands still from here on


def _frames(seconds: float = 90.0) -> list[wire.ImuBatch]:
    w = SimulatedWalker("ff1", None, WalkerSettings(rate_hz=RATE_HZ), 6, start_t=0.0, floors=(0, 0), attitude=False)
    w.stand_still(math.inf, at=STOP_S)
    b = w.next_batch(int(seconds * RATE_HZ))
    return list(wire.imu_batches_from_arrays("ff1", "p", b.t, b.acc, b.gyr, b.mag, b.pressure_t, b.pressure,
                                             carry="handheld", per_batch=PER_FRAME, boot="b"))


FRAMES = _frames()


def _ok(t: float) -> bytes:
    return wire.encode(wire.Ack(responder="ff1", id="man-down-prompt", action="ok", at=1.7e9 + t, t=t))


@functools.lru_cache(maxsize=4)
def _run(answers: tuple = ()) -> list[wire.Status]:
    """The frames at 10 a second with a Status a second; ``answers``: device times of "I'm OK",
    each given with the first frame that reaches it."""
    core, statuses, pending = IncidentCore(CFG), [], sorted(answers)
    for k, f in enumerate(FRAMES):
        rt = 100.0 + 0.1 * k
        core.feed(Inbound("imu", KEY, wire.encode(f), rt))
        while pending and pending[0] <= f.t[-1]:
            core.feed(Inbound("ack", ACK_KEY, _ok(pending.pop(0)), rt))
        if k % 10 == 0:
            statuses += [o.message for o in core.tick(rt) if isinstance(o.message, wire.Status)]
    return statuses


def _first(statuses, cond):
    return next((s for s in statuses if cond(s)), None)


def _down(s):
    return "man_down" in s.alarms


def _asking(s):
    return s.man_down_at is not None and not _down(s)


def test_a_still_responder_is_asked_before_man_down_is_raised_at_the_time_it_said():
    statuses = _run()
    asked, down = _first(statuses, _asking), _first(statuses, _down)
    assert asked is not None and down is not None
    # asked PROMPT_BEFORE_S before, at the newest sample's time; raised at the time announced
    assert asked.t == pytest.approx(asked.man_down_at - PROMPT_BEFORE_S, abs=1.0)
    assert down.t == pytest.approx(asked.man_down_at, abs=1.0) and down.man_down_at == asked.man_down_at
    assert STOP_S + 30.0 <= down.t <= STOP_S + 38.0  # 30 s still (the PASS rule) + the state's decision lag
    assert all(s.man_down_at is None for s in statuses if s.t < STOP_S + 15.0)  # walking and early stillness: no prompt


def test_an_answer_starts_the_no_motion_clock_again_and_no_answer_then_raises_man_down():
    first = _first(_run(), _asking)
    answer = first.t + 3.0  # the wearer taps "I'm OK" 3 s into the prompt
    statuses = _run((answer,))
    after = [s for s in statuses if s.t > answer + 1.0]
    assert not any(_down(s) for s in statuses if s.t < answer + 30.0)  # the man-down of the unanswered run is not raised
    assert after and all(s.ok_at == pytest.approx(answer) for s in after)
    again = _first(after, _asking)  # still after the answer: asked again, then raised, a full no-motion time later
    down = _first(after, _down)
    pipeline = tracker_settings_for(CFG).pipeline
    assert again.man_down_at == pytest.approx(answer + pipeline.no_motion_after_s + pipeline.state_delay_s)
    assert again.t == pytest.approx(again.man_down_at - PROMPT_BEFORE_S, abs=1.0)
    assert down.t == pytest.approx(again.man_down_at, abs=1.0)


def test_an_answer_from_before_the_stillness_changes_nothing():
    ref = _first(_run(), _down)
    down = _first(_run((STOP_S - 5.0,)), _down)
    assert down.t == ref.t and down.man_down_at == ref.man_down_at


def test_an_answer_says_when_on_the_device_clock():
    with pytest.raises(pydantic.ValidationError, match="device clock"):
        wire.Ack(responder="ff1", id="p", action="ok", at=1.7e9)
    core = IncidentCore(CFG)
    core.feed(Inbound("imu", KEY, wire.encode(FRAMES[0]), 100.0))
    core.feed(Inbound("ack", ACK_KEY, b"\x81\xa1v\x01", 100.1))  # not an Ack: counted, the core goes on
    assert core.unattributed.get("ack_invalid") == 1 and core.counters.errors == 0


def test_an_answer_from_a_responder_gone_quiet_reaches_the_console_at_the_next_tick():
    """A silent responder's Status goes out every ``idle_status_every_s``; the wearer's answer is
    not left waiting for it (CI saw the console learn of an answer 5 s late, after the phone's
    frames had stopped): the tick after the answer carries it."""
    core = IncidentCore(CFG)
    for k, f in enumerate(FRAMES[:50]):
        core.feed(Inbound("imu", KEY, wire.encode(f), 100.0 + 0.1 * k))
    sent = {}
    for k in range(1, 31):  # 30 s of silence, a tick a second: idle Statuses only every few seconds
        now = 105.0 + k
        sent[now] = [o.message for o in core.tick(now) if isinstance(o.message, wire.Status)]
    quiet = [now for now, st in sent.items() if now > 115.0 and st]
    assert len(quiet) < 15, quiet  # idle: not every tick (else this test shows nothing)
    answer = FRAMES[49].t[-1] + 1.0
    for now in (136.0, 136.5):  # whichever tick comes next after the answer
        core.feed(Inbound("ack", ACK_KEY, _ok(answer), now - 0.2))
        out = [o.message for o in core.tick(now) if isinstance(o.message, wire.Status)]
        assert out and out[-1].ok_at == pytest.approx(answer), (now, out)
        answer += 1.0


def test_a_quiet_responders_roll_call_answer_reaches_the_console_at_the_next_tick():
    """The same for a roll call: the order and its acknowledgement, on a responder gone quiet,
    show in the Status of the tick that follows the acknowledgement."""
    core = IncidentCore(CFG)
    for k, f in enumerate(FRAMES[:50]):
        core.feed(Inbound("imu", KEY, wire.encode(f), 100.0 + 0.1 * k))
    for k in range(1, 21):
        core.tick(105.0 + k)
    order = wire.Command(responder="ff1", id="par-1", action="par", issued_at=1.7e9 + 125.0)
    core.feed(Inbound("command", wire.key(CFG.id, "ff1", "command"), wire.encode(order), 125.2))
    out = [o.message for o in core.tick(126.0) if isinstance(o.message, wire.Status)]
    assert out and out[-1].commands["par"]["acked_at"] is None, out  # the order itself: waiting
    core.feed(Inbound("ack", ACK_KEY, wire.encode(wire.Ack(responder="ff1", id="par-1", action="par",
                                                           at=1.7e9 + 126.3)), 126.4))
    out = [o.message for o in core.tick(127.0) if isinstance(o.message, wire.Status)]
    assert out and out[-1].commands["par"]["acked_at"] == pytest.approx(1.7e9 + 126.3), out


def test_a_crowd_gone_quiet_shows_a_roll_call_and_its_answers_at_the_next_tick():
    """Idle Statuses go out a share per tick (a crowd does not answer in step); an order and the
    answers to it are not idle news: every responder's Status carries them at the next tick
    (CI's console once showed two answers while the third responder's order was not yet known)."""
    core = IncidentCore(CFG)
    ids = [f"q{k}" for k in range(6)]
    for rid in ids:
        for k, f in enumerate(FRAMES[:50]):
            core.feed(Inbound("imu", wire.key(CFG.id, rid, "imu"), wire.encode(f.model_copy(update={"responder": rid})),
                              100.0 + 0.1 * k))
    for k in range(1, 21):
        core.tick(105.0 + k)
    for rid in ids:
        order = wire.Command(responder=rid, id="par-2", action="par", issued_at=1.7e9 + 125.0)
        core.feed(Inbound("command", wire.key(CFG.id, rid, "command"), wire.encode(order), 125.2))
    seen = {o.message.responder: o.message for o in core.tick(126.0) if isinstance(o.message, wire.Status)}
    assert sorted(seen) == ids and all(s.commands["par"]["acked_at"] is None for s in seen.values())
    for rid in ids[:3]:
        core.feed(Inbound("ack", wire.key(CFG.id, rid, "ack"),
                          wire.encode(wire.Ack(responder=rid, id="par-2", action="par", at=1.7e9 + 126.3)), 126.4))
    seen = {o.message.responder: o.message for o in core.tick(127.0) if isinstance(o.message, wire.Status)}
    assert set(ids[:3]) <= set(seen), sorted(seen)
    assert all(seen[rid].commands["par"]["acked_at"] is not None for rid in ids[:3])

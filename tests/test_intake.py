"""Isolation (issue 20, part 1): the intake's size check, admission budget and per-source
budgets; the rate-limited reject log; responders that leave; memory bounded under any input."""
from __future__ import annotations

import gc
import io
import itertools
import logging
import math
import os
import subprocess
import sys
import tracemalloc

import msgpack
import numpy as np
import pytest

from service.core.incident_core import CoreSettings, Inbound, IncidentCore
from service.core.intake import BAD_KEY, NEW_IDS, Intake, IntakeSettings
from service.core.rejectlog import RejectLog
from service.protocol import wire
from service.protocol.incident import default_incident
from tests.walkers import walk

CFG = default_incident()


def key(rid, kind="imu"):
    return f"firetrack/{CFG.id}/{rid}/{kind}"


def parts(rid, kind="imu"):
    """The key as the shell reads it at its edge (what the intake takes)."""
    return wire.read_key(key(rid, kind))


# --------------------------------------------------------------------------------------
# The intake on its own
# --------------------------------------------------------------------------------------
def test_size_and_keys_are_judged_before_anything_else():
    it = Intake()
    assert it.admit(parts("ff1"), wire.MAX_PAYLOAD_BYTES + 1, 0.0) == ("oversize", "ff1")
    assert it.admit(parts("x" * 10_000), 10, 0.0) == ("bad_key", BAD_KEY)
    assert it.admit(parts("a b"), 10, 0.0) == ("bad_key", BAD_KEY)
    assert it.admit(parts("ff1"), 100, 0.0) == (None, "ff1")
    assert it.counts == {"oversize": 1, "bad_key": 2}


def test_new_ids_are_admitted_within_the_budget_and_the_cap():
    it = Intake(IntakeSettings(admit_burst=10, admit_per_s=2.0, max_responders=15))
    verdicts = [it.admit(parts(f"r{i}"), 100, 0.0)[0] for i in range(50)]
    assert verdicts.count(None) == 10 and verdicts.count("not_admitted") == 40
    assert it.admit(parts("r0"), 100, 0.1) == (None, "r0")  # an admitted id stays admitted
    later = [it.admit(parts(f"s{i}"), 100, 2.0)[0] for i in range(10)]  # 2 s at 2 ids/s
    assert later.count(None) == 4
    much_later = [it.admit(parts(f"t{i}"), 100, 100.0)[0] for i in range(10)]
    assert much_later.count(None) == 1 and it.responders == 15  # the cap
    it.forget("r1")  # a responder that left frees its place
    assert it.admit(parts("u0"), 100, 100.0)[0] is None


def test_the_roster_is_always_admitted_and_roster_only_admits_nobody_else():
    it = Intake(IntakeSettings(admit_burst=1, roster=frozenset({"alpha", "bravo"}), roster_only=True))
    assert it.admit(parts("alpha"), 1, 0.0)[0] is None and it.admit(parts("bravo"), 1, 0.0)[0] is None
    assert it.admit(parts("mallory"), 1, 0.0) == ("not_admitted", NEW_IDS)


def test_a_flooding_source_is_throttled_named_and_the_others_are_not():
    it = Intake(IntakeSettings(source_rate=100.0, source_burst=200.0, flood_alarm_s=30.0))
    t = np.arange(30_000) * 1e-3  # 1000 messages/s for 30 s from one source ...
    flood = [it.admit(parts("evil"), 200, float(x))[0] for x in t]
    honest = [it.admit(parts("ff1"), 800, float(x))[0] for x in t[::100]]  # ... and 10/s from another
    assert flood.count(None) == pytest.approx(200 + 100 * 30, abs=2) and flood.count("throttled") > 26_000
    assert honest.count(None) == len(honest)
    assert it.flooding("evil", 30.0) and not it.flooding("ff1", 30.0)
    assert it.flooding_sources(30.0) == ["evil"] and not it.flooding("evil", 61.0)


def test_a_sender_of_garbage_gets_the_small_budget_until_it_behaves():
    s = IntakeSettings(source_rate=100.0, source_burst=100.0, bad_after=5, bad_window_s=10.0, bad_rate=2.0, bad_burst=2.0)
    it = Intake(s)
    for i in range(5):
        assert it.admit(parts("noisy"), 10, i * 0.01)[0] is None
        it.note_reject("noisy", i * 0.01)
    taken = [it.admit(parts("noisy"), 10, 0.1 + i * 0.01)[0] for i in range(100)]
    assert taken.count(None) <= 3  # 2 at once, then 2/s
    # quiet and clean for the window: the ordinary budget again
    assert [it.admit(parts("noisy"), 10, 30.0 + i * 0.001)[0] for i in range(50)].count(None) == 50


# --------------------------------------------------------------------------------------
# The log
# --------------------------------------------------------------------------------------
def test_the_log_of_a_flood_is_a_few_lines_per_source_and_a_summary():
    stream = io.StringIO()
    logger = logging.getLogger("firetrack.test.rejectlog")
    logger.handlers[:] = [logging.StreamHandler(stream)]
    logger.propagate = False
    logger.setLevel(logging.WARNING)
    rl = RejectLog(logger, window_s=10.0, lines_per_source=3, lines_per_window=40, max_sources=50)
    for i in range(100_000):  # 100 k rejects in 30 s from 1000 sources, with long details
        rl.note(f"src{i % 1000}", ("msgpack", "schema")[i % 2], "x" * 5000, i * 3e-4)
    rl.flush(30.0)
    text = stream.getvalue()
    assert rl.lines <= 3 * (40 + 51)  # per window: full lines + a summary per source (+ others)
    assert len(text) < 60_000 and "more messages rejected in the last" in text and "<other sources>" in text
    assert max(len(line) for line in text.splitlines()) < 600


# --------------------------------------------------------------------------------------
# The core: 5,000 new ids, expiry, bounded memory and status
# --------------------------------------------------------------------------------------
def test_a_wearable_added_to_the_roster_mid_incident_is_admitted_with_roster_only():
    """serve --roster-only: the roster file gains a wearable while the service runs; the access
    policy it sends the core (service.cli.serve._watch_roster) carries the roster's wearables,
    and from that message on the new name is admitted (before it, refused)."""
    from service.protocol.access import Roster, access_message

    core = IncidentCore(CFG, CoreSettings(intake=IntakeSettings(roster=frozenset({"ff1"}), roster_only=True)))
    roster = Roster(incident=CFG.id)
    roster.add("ff1", "wearable")
    roster.add("console", "console")
    core.feed(Inbound("access", key("svc", "access"), wire.encode(access_message(roster)), 1.0))
    assert core.admit("imu", key("ff9"), 100, 2.0) == "not_admitted"
    roster.add("ff9", "wearable")  # firetrack certs issue --role wearable --name ff9, mid-incident
    roster.add("ff7", "wearable")
    acc = access_message(roster)
    assert acc.wearables == ["ff1", "ff7", "ff9"] and acc.operators == ["console"]
    core.feed(Inbound("access", key("svc", "access"), wire.encode(acc), 3.0))
    assert core.admit("imu", key("ff9"), 100, 4.0) is None
    assert core.admit("imu", key("ff1"), 100, 4.0) is None and core.admit("imu", key("zz"), 100, 4.0) == "not_admitted"
    twin = IncidentCore.restore(core.snapshot(), CFG, core.settings)  # a restart from the snapshot keeps it
    assert twin.admit("imu", key("ff7"), 100, 5.0) is None and twin.admit("imu", key("ff8"), 100, 5.0) == "not_admitted"


def frame_payload(rid, seq, t0):
    z = np.zeros((10, 3))
    z[:, 2] = 9.81
    return wire.encode(wire.ImuBatch(responder=rid, device="d", seq=seq, t=t0 + np.arange(10) * 0.01, acc=z,
                                     gyr=np.zeros((10, 3))))


def test_five_thousand_new_ids_are_bounded_by_the_budget_and_expire():
    s = CoreSettings(intake=IntakeSettings(admit_burst=50, admit_per_s=2.0, max_responders=100),
                     expire_after_s=60.0, expire_unplaced_s=20.0)
    core = IncidentCore(CFG, s)
    taken = 0
    for i in range(5000):  # 5,000 ids, one valid frame each, over 25 s
        now = 1000.0 + i * 0.005
        k = key(f"id{i}")
        p = frame_payload(f"id{i}", 0, 10.0)
        if core.admit("imu", k, len(p), now) is None:
            core.feed(Inbound("imu", k, p, now))
            taken += 1
    assert taken == len(core.responders) == pytest.approx(50 + 2 * 25, abs=2)
    status = [o for o in core.tick(1025.0) if isinstance(o.message, wire.Status)]
    assert len(status) == len(core.responders) <= 100  # status traffic follows the responders kept
    assert core.frame_accounting()["not_admitted"] == 5000 - taken
    # silence: each leaves 60 s after its last message (its track would be in the recording)
    core.feed(Inbound("imu", key("id0"), frame_payload("id0", 1, 10.1), 1050.0))
    core.feed(Inbound("imu", key("id0"), frame_payload("id0", 2, 10.2), 1084.0))
    assert len(core.responders) > 1  # the ids admitted last were heard less than 60 s ago
    core.feed(Inbound("imu", key("id0"), frame_payload("id0", 3, 10.3), 1086.0))
    assert set(core.responders) == {"id0"} and core.counters.expired == taken - 1
    # an id whose messages were all garbage (no frame ever released) leaves after 20 s
    assert core.admit("imu", key("junk"), 3, 1090.0) is None
    core.feed(Inbound("imu", key("junk"), b"\xc1\xc1\xc1", 1090.0))
    core.feed(Inbound("presence", key("id0", "presence"), b"1", 1111.0))
    assert set(core.responders) == {"id0"}
    core.feed(Inbound("presence", key("id0", "presence"), b"0", 1147.0))
    assert core.responders == {} and core.intake.responders == 0


def test_memory_is_bounded_under_a_stream_of_hostile_input():
    """Garbage of every kind on valid and invalid keys: what the core keeps stops growing."""
    s = CoreSettings(intake=IntakeSettings(admit_burst=20, admit_per_s=1.0, max_responders=50),
                     expire_unplaced_s=10.0)
    core = IncidentCore(CFG, s)
    rng = np.random.default_rng(0)
    deep = b"\x81\xa1a" * 2000 + b"\xc0"

    def payload(i):
        kind = i % 5
        if kind == 0:
            return rng.bytes(int(rng.integers(1, 300)))
        if kind == 1:
            return msgpack.packb({"v": 1, "kind": "imu", "responder": f"r{i % 97}", "seq": -i, "t": "no"})
        if kind == 2:
            return deep
        if kind == 3:
            return frame_payload(f"r{i % 97}", int(rng.integers(0, 10**6)), float(rng.uniform(0, 1e6)))
        return msgpack.packb([i] * 10)

    def burst(start, n):
        for i in range(start, start + n):
            now = 2000.0 + i * 0.002
            rid = f"r{i % 97}" if i % 3 else f"{os.urandom(4).hex()}"
            k = key(rid, "imu" if i % 4 else "fix")
            p = payload(i)
            if core.admit(k.rsplit("/", 1)[1], k, len(p), now) is None:
                core.feed(Inbound(k.rsplit("/", 1)[1], k, p, now))

    logging.getLogger("firetrack.service").setLevel(logging.CRITICAL)
    try:
        burst(0, 3000)
        gc.collect()
        tracemalloc.start()
        burst(3000, 6000)
        gc.collect()
        mid, _ = tracemalloc.get_traced_memory()
        burst(9000, 12000)
        gc.collect()
        end, _ = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    finally:
        logging.getLogger("firetrack.service").setLevel(logging.NOTSET)
    assert len(core.responders) <= 50 and len(core.roster.presence) <= core.roster.MAX_PRESENCE
    assert end - mid < 2_000_000  # twice the messages, no more than noise in what is kept
    assert core.counters.errors == 0


def test_silent_ids_cost_little_status_traffic_and_an_alarm_goes_out_at_once():
    """A responder heard in the last ``idle_after_s`` gets a Status every tick; a silent one every
    ``idle_status_every_s``, and at once when its alarms change."""
    from service.protocol.schema import LOST_CONTACT_S

    s = CoreSettings(idle_after_s=2.0, idle_status_every_s=5.0)
    core = IncidentCore(CFG, s)
    for rid in ("talk", "quiet"):
        core.feed(Inbound("imu", key(rid), frame_payload(rid, 0, 10.0), 1000.0))
    sent = {"talk": [], "quiet": []}  # (time, alarms) of every Status answered
    for k in range(1, 41):  # 40 ticks, 1 s apart; "talk" sends a frame before each, "quiet" never again
        now = 1000.0 + k
        core.feed(Inbound("imu", key("talk"), frame_payload("talk", k, 10.0 + 0.1 * k), now - 0.5))
        for o in core.tick(now):
            if isinstance(o.message, wire.Status):
                sent[o.message.responder].append((now, tuple(o.message.alarms)))
    assert len(sent["talk"]) == 40
    quiet = sent["quiet"]
    assert len(quiet) < 40 / 3  # instead of 40
    for (t0, a0), (t1, a1) in zip(quiet, quiet[1:]):
        if t0 >= 1000.0 + s.idle_after_s:
            assert t1 - t0 >= s.idle_status_every_s or a1 != a0, (t0, t1, a0, a1)
    first = next(t for t, a in quiet if "lost_contact" in a)  # the alarm went out the tick it was raised
    assert first <= 1000.0 + LOST_CONTACT_S + 1.0


def test_garbage_on_a_fresh_id_makes_no_responder_until_one_of_its_messages_decodes():
    """An admitted id whose messages do not decode is a newcomer: no tracker, no Status, its
    rejects counted by reason; its first good frame makes the responder, which carries them.
    A newcomer that stays silent is forgotten with its budget, its counts kept."""
    s = CoreSettings(expire_unplaced_s=20.0)
    core = IncidentCore(CFG, s)
    bad = [("imu", b"\xc1\xc1"), ("imu", frame_payload("someone_else", 0, 10.0)),
           ("imu", msgpack.packb({"v": 99, "kind": "imu"})),  # (a fix for a fresh id is refused: it makes nobody)
           ("imu", msgpack.packb([1, 2, 3]))]
    for i, (kind, p) in enumerate(bad * 6):  # 24 rejects: more than the burst alarm's threshold
        now = 1000.0 + 0.1 * i
        assert core.admit(kind, key("fresh", kind), len(p), now) is None
        core.feed(Inbound(kind, key("fresh", kind), p, now))
    assert core.responders == {}
    assert [o for o in core.tick(1003.0) if o.key.endswith("/fresh/status")] == []
    acc = core.frame_accounting()
    assert (acc["msgpack"], acc["schema"], acc["version"], acc["not_a_map"]) == (6, 6, 6, 6)
    core.feed(Inbound("imu", key("fresh"), frame_payload("fresh", 0, 10.0), 1003.5))
    assert set(core.responders) == {"fresh"} and core.responders["fresh"].first_heard == 1000.0
    st = next(o.message for o in core.tick(1004.0) if o.key.endswith("/fresh/status"))
    assert (st.rejected["msgpack"], st.rejected["schema"], st.rejected["version"]) == (6, 6, 6)
    assert "rejected_frames" in st.alarms and st.first_heard == 1000.0
    assert core.frame_accounting()["msgpack"] == 6  # counted once, now as the responder's
    # a newcomer silent for expire_unplaced_s goes, with its intake budget; its counts stay in the incident's
    p = b"\xc1"
    assert core.admit("imu", key("junk"), len(p), 1005.0) is None
    core.feed(Inbound("imu", key("junk"), p, 1005.0))
    assert "junk" in core.intake.sources and "junk" not in core.responders
    core.feed(Inbound("presence", key("fresh", "presence"), b"1", 1026.0))
    assert "junk" not in core.intake.sources and core.frame_accounting()["newcomer_msgpack"] == 1


def test_a_newcomer_survives_a_snapshot():
    core = IncidentCore(CFG)
    for i in range(3):
        core.feed(Inbound("imu", key("fresh"), b"\xc1", 1000.0 + i))
    back = IncidentCore.restore(core.snapshot(), CFG)
    assert back.responders == {} and back.frame_accounting()["msgpack"] == 3
    back.feed(Inbound("imu", key("fresh"), frame_payload("fresh", 0, 10.0), 1004.0))
    assert back.responders["fresh"].gate.counts["msgpack"] == 3 and back.responders["fresh"].first_heard == 1000.0


def test_the_idle_statuses_of_a_crowd_admitted_together_are_spread_over_ticks():
    """Ids admitted in the same second fall silent together; their idle Statuses go out a share
    per tick, not all in the same tick every ``idle_status_every_s``, and each still gets one
    about that often."""
    s = CoreSettings(idle_after_s=2.0, idle_status_every_s=5.0, expire_after_s=600.0, expire_unplaced_s=600.0)
    core = IncidentCore(CFG, s)
    n = 100
    for i in range(n):
        core.feed(Inbound("imu", key(f"c{i}"), frame_payload(f"c{i}", 0, 10.0), 1000.0 + i * 1e-3))
    per_tick, times = [], {f"c{i}": [] for i in range(n)}
    for k in range(1, 61):
        now = 1000.0 + k
        sent = [o.message.responder for o in core.tick(now) if isinstance(o.message, wire.Status)]
        per_tick.append(len(sent))
        for rid in sent:
            times[rid].append(now)
    settled = per_tick[20:]  # after the alarms they all raise together (lost contact at 10 s) have gone out
    assert max(settled) <= math.ceil(n / s.idle_status_every_s) + 1, per_tick
    gaps = [b - a for ts in times.values() for a, b in itertools.pairwise(ts) if a >= 1020.0]
    assert min(gaps) >= s.idle_status_every_s and max(gaps) <= s.idle_status_every_s + 2.0, sorted(set(gaps))
    assert sum(settled) == pytest.approx(n * 40 / s.idle_status_every_s, rel=0.1)


_CHURN = """
import sys
from service.shell.snapshots import fix_mmap_threshold
def rss_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
if sys.argv[1] == "fixed":
    assert fix_mmap_threshold(128 * 1024)
big = bytearray(16 << 20)  # freed, it raises glibc's dynamic threshold to 16 MB
del big
keep, blocks = [], []
before = rss_mb()
for k in range(60):  # snapshot-sized buffers between small blocks that stay: the service's heap churn
    blocks.append(bytes(1 << 20) + bytes([k]))
    keep.append(bytearray(2000))
grown = rss_mb()
del blocks
print(grown - before, grown - rss_mb())
"""


def _glibc() -> bool:
    try:
        return sys.platform.startswith("linux") and bool(os.confstr("CS_GNU_LIBC_VERSION"))
    except (ValueError, OSError):
        return False


@pytest.mark.skipif(not _glibc(), reason="needs glibc's mallopt and /proc/self/status")
def test_freed_big_buffers_go_back_to_the_system_with_the_services_mmap_threshold():
    """Big short-lived buffers (a snapshot's bytes every few seconds) between small blocks that
    stay: with the service's fixed mmap threshold (ServiceSettings.mmap_threshold_bytes) what
    they took is returned when they are freed; with glibc's dynamic one, raised by an earlier
    big block, they come from the heap and much of it stays resident."""
    grown, back = map(float, subprocess.run([sys.executable, "-c", _CHURN, "fixed"], capture_output=True, text=True,
                                            check=True).stdout.split())
    assert grown > 50 and back > 0.9 * grown


def test_garbage_fixes_on_a_responders_key_never_throttle_its_frames():
    """Issue 32, attack 4: an anchor sends 25 malformed fixes/s on ff2's fix key for 30 s while
    ff2's wearable sends its 10 frames/s. Zenoh cannot tell the subscriber who sent a sample,
    but the router lets only ff2's wearable put on ``ff2/imu``: the fixes spend the ``fix`` lane
    of ff2, held to the bad-sender budget, named ``ff2/fix``; every frame of ff2 is taken and ff2
    carries no ``flooding`` alarm."""
    core = IncidentCore(CFG)
    garbage = msgpack.packb({"v": 1, "kind": "fix", "responder": "ff2", "t": "soon", "source": "checkpoint"})
    frames_taken = fixes_taken = fixes_refused = 0
    for k in range(300):  # 30 s
        now = 1000.0 + 0.1 * k
        p = frame_payload("ff2", k, 10.0 + 0.1 * k)
        if core.admit("imu", key("ff2"), len(p), now) is None:
            core.feed(Inbound("imu", key("ff2"), p, now))
            frames_taken += 1
        for j in range(2 + (k % 2)):  # 25 per second
            t = now + 0.03 * (j + 1)
            if core.admit("fix", key("ff2", "fix"), len(garbage), t) is None:
                core.feed(Inbound("fix", key("ff2", "fix"), garbage, t))
                fixes_taken += 1
            else:
                fixes_refused += 1
    st = core.status_of(core.responders["ff2"], 1030.0)
    assert frames_taken == 300 and st.frames == 300 and "throttled" not in st.rejected
    assert fixes_refused > 500 and st.rejected["fix_throttled"] == fixes_refused  # the bad-sender budget: ~5/s
    assert "flooding" not in st.alarms and core.flooding_sources(1030.0) == ["ff2/fix"]
    # a flood on the frames' key throttles the frames' lane: that is ff2's own wearable
    for i in range(5000):
        core.admit("imu", key("ff2"), 3, 1030.0 + i * 1e-4)
    assert core.intake.flooding("ff2", 1031.0) and "flooding" in core.status_of(core.responders["ff2"], 1031.0).alarms


def test_budgets_are_per_lane():
    it = Intake(IntakeSettings(source_rate=10.0, source_burst=10.0))
    assert it.admit(parts("ff1"), 10, 0.0)[0] is None  # its wearable's first frame (a fix alone makes nobody)
    assert [it.admit(parts("ff1", "fix"), 10, 0.0)[0] for _ in range(20)].count("throttled") == 10
    assert [it.admit(parts("ff1"), 10, 0.0)[0] for _ in range(9)] == [None] * 9
    assert it.flooding("ff1", 0.0, lane="fix") and not it.flooding("ff1", 0.0)
    assert it.flooding_sources(0.0) == ["ff1/fix"] and it.dropped_of("ff1") == {"fix_throttled": 10}


def test_fixes_for_unknown_responders_make_no_responder():
    """Issue 32, attack 5: an anchor's fixes for ids nobody has made responders, published to
    the consoles. Now such a fix keeps no intake state and makes no responder, Status or
    newcomer; it is held a few seconds (bounded) so that a wearable's door fix sent just before
    its first frame still places it, and dropped and counted otherwise."""
    core = IncidentCore(CFG)
    for i in range(1000):  # fixes for 1000 ids nobody has, in 10 s
        rid = f"ghost{i}"
        fix = wire.encode(wire.Fix.checkpoint(rid, 10.0, x=1.0, y=2.0, floor=0))
        now = 1000.0 + i * 0.01
        if core.admit("fix", key(rid, "fix"), len(fix), now) is None:
            core.feed(Inbound("fix", key(rid, "fix"), fix, now))
    out = core.tick(1010.0)
    assert core.responders == {} and core.roster.newcomers == {} and not [o for o in out if "/ghost" in o.key]
    assert core.intake.responders == 0 and sum(len(v) for v in core.fixes.held.values()) <= core.fixes.MAX_HELD_FIXES
    door = wire.encode(wire.Fix.checkpoint("ff7", 10.0, x=10.0, y=-5.0, floor=0, sigma=0.2))
    assert core.admit("fix", key("ff7", "fix"), len(door), 1010.5) is None
    core.feed(Inbound("fix", key("ff7", "fix"), door, 1010.5))
    core.feed(Inbound("presence", key("x", "presence"), b"1", 1025.0))  # time passes: the ghosts' fixes go
    assert core.fixes.held == {} or set(core.fixes.held) == {"ff7"}
    assert core.frame_accounting()["fix_unknown_responder"] >= 1000 - core.fixes.MAX_HELD_FIXES
    # a wearable whose door fix came just before its first frame is placed by it
    core2 = IncidentCore(CFG)
    core2.feed(Inbound("fix", key("ff7", "fix"), door, 1010.5))
    assert core2.responders == {}
    p = frame_payload("ff7", 0, 10.0)
    core2.feed(Inbound("imu", key("ff7"), p, 1011.0))
    tr = core2.responders["ff7"].tracker
    assert tr.fixes_applied + tr.fixes_queued == 1 and "fix_unknown_responder" not in core2.frame_accounting()


def test_a_source_pickled_before_lanes_resumes_as_its_frames_lane():
    """A snapshot of an older service (one bucket per source) still resumes."""
    import pickle
    from collections import deque

    from service.core.intake import SourceState, TokenBucket

    it = Intake()
    old = SourceState.__new__(SourceState)
    old.__dict__.update({"bucket": TokenBucket(100.0, 4000.0, 0.0), "rejects": deque(), "bad": False, "throttled": 3,
                         "last_throttled": 5.0, "dropped": {"throttled": 3}})
    it.sources["ff2"] = old
    back = pickle.loads(pickle.dumps(it))
    assert back.flooding("ff2", 10.0) and back.admit(parts("ff2"), 10, 11.0) == (None, "ff2")
    assert back.dropped_of("ff2") == {"throttled": 3}

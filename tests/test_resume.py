"""Restart recovery (issue 20, part 4): snapshots of the core, a state file beside the recording,
segments, resume after a crash and reprocess of the segmented recording."""
from __future__ import annotations

import math
import os
import pickle
import subprocess
import sys
import time

import msgpack
import numpy as np
import pytest

from service.core import snapshot as snapshots
from service.core.incident_core import Inbound, IncidentCore
from service.protocol import wire
from service.protocol.incident import default_incident
from service.review.recorder import IncidentRecorder, segment_paths
from service.review.reprocess import reprocess
from service.review.resume import Base, StateFile, resume, state_path
from tests.walkers import walk

CFG = default_incident()


def inputs_of(w, rid="ff1", rt0=100.0, fix=True):
    """A walker's frames as the shell takes them (receive time 10 frames/s), after a checkpoint
    at its start."""
    out = []
    if fix:
        cp = wire.Fix.checkpoint(rid, float(w.t[0]), x=float(w.x[0]), y=float(w.y[0]), floor=0, sigma=0.3)
        out.append(Inbound("fix", wire.key(CFG.id, rid, "fix"), wire.encode(cp), rt0 - 0.05))
    out += [Inbound("imu", wire.key(CFG.id, rid, "imu"), wire.encode(f), rt0 + k * 0.1) for k, f in enumerate(w.frames)]
    return out


def poses(out):
    return [o.message for o in out if isinstance(o.message, wire.Pose)]


# --------------------------------------------------------------------------------------
# Snapshots
# --------------------------------------------------------------------------------------
def test_a_restored_core_goes_on_like_the_uninterrupted_one():
    items = inputs_of(walk(seconds=90.0, seed=11)) + inputs_of(walk("ff2", seconds=90.0, seed=12), "ff2")
    items.sort(key=lambda i: i.received)
    cut = len(items) // 2
    core = IncidentCore(CFG)
    for i in range(0, cut, 200):
        core.feed_round(items[i:min(i + 200, cut)])
    blob = core.snapshot()
    twin = IncidentCore.restore(blob, CFG)
    assert core.snapshot() == blob  # taking a snapshot changes nothing
    for rid in ("ff1", "ff2"):  # the whole track so far comes back: every pose, the window's as estimated now
        mine, theirs = core.track(rid), twin.track(rid)
        assert mine["smoothed"] and theirs["smoothed"] and len(mine["track"]["t"]) > 50
        for c in ("t", "x", "y", "heading", "floor"):
            np.testing.assert_allclose(theirs["track"][c], mine["track"][c], rtol=0, atol=1e-9)
    a, b = [], []
    for i in range(cut, len(items), 200):
        a += poses(core.feed_round(items[i:i + 200]))
        b += poses(twin.feed_round(items[i:i + 200]))
    assert len(a) == len(b) > 100
    assert [p.steps for p in a] == [p.steps for p in b]  # the same step counts
    worst = max(math.hypot(p.x - q.x, p.y - q.y) for p, q in zip(a, b))
    assert worst < 0.5  # the graph restarted from the newest pose: its window's correlations are gone
    for rid in ("ff1", "ff2"):
        r, t = core.responders[rid], twin.responders[rid]
        assert (r.gate.accepted, r.gate.next_seq, r.tracker.steps) == (t.gate.accepted, t.gate.next_seq, t.tracker.steps)


def test_a_snapshot_names_nothing_but_the_projects_classes():
    class Evil:
        def __reduce__(self):
            return (os.system, ("echo pwned",))

    with pytest.raises(snapshots.SnapshotError, match="may not name"):
        snapshots.loads(snapshots.MAGIC + pickle.dumps(Evil()))
    # a function of the project (not a class) is refused too
    from service.review import resume as resume_module  # noqa: F401  (a module with side effects)

    class Sneaky:
        def __reduce__(self):
            from pdr.io import load
            return (load, ("/etc/passwd",))

    with pytest.raises(snapshots.SnapshotError, match="classes only"):
        snapshots.loads(snapshots.MAGIC + pickle.dumps(Sneaky()))
    with pytest.raises(snapshots.SnapshotError, match="not a firetrack core snapshot"):
        snapshots.loads(b"garbage")
    with pytest.raises(snapshots.SnapshotError, match="cannot be read"):
        snapshots.loads(snapshots.MAGIC + b"\x80\x05garbage")


def _eventful_inputs():
    """Two walkers with checkpoints; one's frames swapped in pairs and one held back (the gate
    holds and a tick releases), presence, a roll call and its ack, an operator's fix, an
    oversize message through the intake, and a crowd of ids that send one frame and fall
    silent (a flood's admitted ids)."""
    items = inputs_of(walk(seconds=40.0, seed=21)) + inputs_of(walk("ff2", seconds=40.0, seed=22), "ff2", rt0=100.03)
    frames2 = [i for i in items if i.kind == "imu" and "/ff2/" in i.key]
    for a, b in zip(frames2[10:200:7], frames2[11:200:7]):  # out of order: held until the missing one
        a_rt, b_rt = a.received, b.received
        items[items.index(a)], items[items.index(b)] = b._replace(received=a_rt), a._replace(received=b_rt)
    gone = frames2[250]
    items.remove(gone)  # never comes: the gate holds the next ones until a tick gives up on it
    for k in range(30):
        f = walk(f"idle{k:02d}", seconds=0.1, seed=100 + k).frames[0]
        items.append(Inbound("imu", wire.key(CFG.id, f"idle{k:02d}", "imu"), wire.encode(f), 101.0 + 0.1 * k))
    items.append(Inbound("presence", wire.key(CFG.id, "idle05", "presence"), b"0", 110.0))
    items.append(Inbound("presence", wire.key(CFG.id, "idle06", "presence"), b"0", 111.0))
    items.append(Inbound("presence", wire.key(CFG.id, "idle06", "presence"), b"1", 112.0))
    cmd = wire.Command(responder="idle07", action="par", id="p1", issued_at=115.0, issued_by="ic")
    items.append(Inbound("command", wire.key(CFG.id, "idle07", "command"), wire.encode(cmd), 115.0))
    ack = wire.Ack(responder="idle07", action="par", id="p1", at=117.0)
    items.append(Inbound("ack", wire.key(CFG.id, "idle07", "ack"), wire.encode(ack), 117.0))
    w1 = walk(seconds=40.0, seed=21)
    for rid, k, rt in (("ff1", 2500, 125.5), ("idle11", 5, 126.5)):  # operators' fixes: a walker, an idle id
        t = float(w1.t[k]) if rid == "ff1" else 1000.05
        fix = wire.Fix.checkpoint(rid, t, x=float(w1.x[k]), y=float(w1.y[k]), floor=0, sigma=0.5)
        op = wire.OperatorAction(operator="ic", action="fix", responder=rid, fix=wire.encode(fix), utc=rt)
        items.append(Inbound("op", wire.key(CFG.id, "console", "op"), wire.encode(op), rt))
    return sorted(items, key=lambda i: i.received)


def test_a_responders_kept_pickle_is_its_pickle_now_whenever_a_snapshot_reuses_it():
    """Incremental snapshots: whatever happened since (frames, held frames released by a tick,
    presence, orders, acks, operator fixes, an oversize message, silence), a responder whose
    pickle the core kept from the last snapshot pickles to the same bytes now, and the idle
    crowd is not pickled again."""
    core = IncidentCore(CFG)
    items = _eventful_inputs()
    oversize_at = len(items) // 3
    checked = reused = 0
    rt = items[0].received
    for i in range(0, len(items), 25):
        for it in items[i:i + 25]:
            if core.admit(it.kind, it.key, len(it.payload), it.received) is None:
                core.feed_round([it])
        if i // 25 == oversize_at // 25:
            k = wire.key(CFG.id, "idle09", "imu")
            assert core.admit("imu", k, wire.MAX_PAYLOAD_BYTES + 1, items[i].received) == "oversize"
        while rt < items[min(i + 25, len(items) - 1)].received:
            rt += 1.0
            core.tick(rt)
        for rid, blob in core.roster.blobs.items():
            assert blob == core.responder_blob(core.responders[rid]), f"{rid}'s kept pickle is stale at item {i}"
            checked += 1
        before = dict(core.roster.blobs)
        core.snapshot()
        reused += sum(1 for rid, b in before.items() if core.roster.blobs.get(rid) is b)
    assert checked > 500 and reused > 500  # the idle ids' pickles were reused, and still right
    st = {rid: core.status_of(core.responders[rid], rt) for rid in ("ff2", "idle05", "idle07", "idle09", "idle11")}
    assert st["ff2"].lost >= 1 and st["idle07"].commands["par"]["acked_at"] == 117.0  # the events above happened
    assert "disconnected" in st["idle05"].alarms and st["idle09"].rejected.get("oversize") == 1
    assert core.responders["ff1"].tracker.fixes_applied >= 2 and core.counters.errors == 0


def test_an_incremental_snapshot_restores_the_core_a_whole_snapshot_restores():
    """A snapshot that reused the silent responders' pickles restores a core that goes on, bit
    for bit, like one restored from a snapshot that pickled every responder afresh, and with
    the uninterrupted core's step counts and statuses."""
    items = _eventful_inputs()
    cut = len(items) * 2 // 3
    core = IncidentCore(CFG)
    for i in range(0, cut, 40):
        core.feed_round(items[i:min(i + 40, cut)])
        core.tick(items[min(i + 40, cut) - 1].received)
        core.snapshot()
    kept = dict(core.roster.blobs)
    incremental = core.snapshot()
    assert sum(1 for rid, b in kept.items() if core.roster.blobs[rid] is b) >= 30  # the idle crowd was reused
    core.roster.blobs.clear()
    whole = core.snapshot()
    twins = [IncidentCore.restore(incremental, CFG), IncidentCore.restore(whole, CFG)]
    out = [[], [], []]
    for i in range(cut, len(items), 40):
        now = items[min(i + 40, len(items)) - 1].received
        for c, o in zip([core] + twins, out):
            o += [m.message for m in c.feed_round(items[i:i + 40]) + c.tick(now)]
    assert len(out[1]) > 100
    assert [wire.encode(m) for m in out[1]] == [wire.encode(m) for m in out[2]]
    sa, sb = ([m for m in o if isinstance(m, wire.Status)] for o in (out[0], out[1]))
    assert [wire.encode(m) for m in sa] == [wire.encode(m) for m in sb]  # every counter, alarm, order, step


def test_a_crowd_of_new_responders_is_pickled_a_batch_per_round_before_the_snapshot():
    """300 ids admitted at once (a flood's burst): the core pickles at most a batch of them per
    call and says how many are left; the shell defers a due snapshot while more than a batch is
    left, and the snapshot it then writes pickles no more than a batch afresh and is the very
    snapshot a whole pickling gives."""
    import threading
    import types

    from service.shell.service import ServiceSettings
    from service.shell.snapshots import SnapshotWriter

    core = IncidentCore(CFG)
    core.feed_round(inputs_of(walk(seconds=3.0, seed=5))[:20])
    core.snapshot()
    for k in range(300):
        f = walk(f"new{k:03d}", seconds=0.1, seed=k).frames[0]
        core.feed_round([Inbound("imu", wire.key(CFG.id, f"new{k:03d}", "imu"), wire.encode(f), 103.0)])
    assert core.prepare_snapshot(100) == 200 and core.prepare_snapshot(0) == 200

    written = []
    settings = ServiceSettings(snapshot_batch=64)
    shell = types.SimpleNamespace(
        state_file=types.SimpleNamespace(write=lambda blob, pos, now: written.append(blob)), recorder_error=None,
        recorder=types.SimpleNamespace(flush=lambda: None, message_count=7), snapshot_error=None, core=core,
        snapshot_feed=None,
        settings=settings, _last_snapshot=100.0, _snapshot_writer=None, snapshots=0, snapshots_skipped=0,
        snapshots_deferred=0, _rec_lock=threading.Lock(), _core_lock=threading.Lock(), clock=lambda: 200.0)
    for name in ("_snapshot_if_due", "_write_snapshot", "_snapshot_failed"):
        setattr(shell, name, types.MethodType(getattr(SnapshotWriter, name), shell))
    made = []
    real = core.roster.blob_of
    core.roster.blob_of = lambda r, refs: made.append(r.id) or real(r, refs)
    import service.shell.snapshots as snapshots_module
    clock = snapshots_module.time.monotonic
    try:
        snapshots_module.time.monotonic = lambda: 106.0  # due (5 s), within two periods: deferred
        rounds = 0
        while not written and rounds < 10:
            shell._snapshot_if_due()
            if shell._snapshot_writer is not None:
                shell._snapshot_writer.join()
            rounds += 1
    finally:
        snapshots_module.time.monotonic = clock
    assert written and shell.snapshots_deferred == 3 and len(made) == 200  # 64, 64, 64, then the last 8 in the snapshot
    del core.roster.blob_of
    core.roster.blobs.clear()
    assert written[0] == core.snapshot()


def test_a_restored_fleets_members_see_its_rows():
    """The handheld members' floor trackers work on views of the fleet's rows; after a restore
    on views of the restored fleet's rows (not copies that the fleet's rounds would leave
    behind)."""
    core = IncidentCore(CFG)
    core.feed_round(inputs_of(walk(seconds=5.0, seed=3))[:40])
    twin = IncidentCore.restore(core.snapshot(), CFG)
    m = twin.responders["ff1"].tracker.model
    rows = m.floor_tracker.rows()
    assert rows[0].base is twin.fleet.rows.fs and np.shares_memory(rows[1], twin.fleet.rows.ring_t[m.slot])


def test_the_state_file_is_replaced_whole_and_checked_on_reading(tmp_path):
    sf = StateFile(tmp_path / "x.mcap.state", "demo", 2)
    sf.write(b"abc", 17, 123.0)
    d = StateFile.read(sf.path)
    assert (d["incident"], d["segment"], d["position"], d["snapshot"]) == ("demo", 2, 17, b"abc")
    assert not (tmp_path / "x.mcap.state.tmp").exists()
    sf.path.write_bytes(b"\x00\x01 not msgpack")
    with pytest.raises(ValueError, match="x.mcap.state"):
        StateFile.read(sf.path)
    sf.path.write_bytes(msgpack.packb({"format": "firetrack-state/1", "incident": "demo"}))
    with pytest.raises(ValueError, match="'segment' is missing"):
        StateFile.read(sf.path)


# --------------------------------------------------------------------------------------
# A service's recording life, without the network: rounds recorded, snapshots, a crash, a resume
# --------------------------------------------------------------------------------------
class MiniShell:
    """What :class:`service.shell.service.IncidentService` does with a recording, in rounds:
    inputs recorded, fed, poses recorded; a snapshot into the state file every ``every`` rounds."""

    def __init__(self, path, core, segment=0, resume_record=None, every=20):
        self.rec = IncidentRecorder(path, CFG.id, segment=segment, resume=resume_record)
        self.core = core
        self.state = StateFile(state_path(segment_paths(path)[0] if segment else path), CFG.id, segment)
        self.every, self.rounds, self.published = every, 0, []

    def round(self, items):
        for m in items:
            self.rec.write(m.key, m.payload, m.received)
        out = self.core.feed_round(items)
        for o in out:
            self.rec.write(o.key, wire.encode(o.message), items[-1].received)
            self.published.append(o.message)
        self.rounds += 1
        if self.rounds % self.every == 0:
            self.rec.flush()
            self.state.write(self.core.snapshot(), self.rec.message_count, items[-1].received)


def _crash(rec: IncidentRecorder) -> None:
    """The process dies: the pending chunk never reaches the file, nor does the summary."""
    os.close(rec._file.fd)
    rec._closed = True


@pytest.mark.parametrize("state_file", ["kept", "missing", "damaged"])
def test_a_crashed_service_resumes_and_reprocess_equals_the_live_poses(tmp_path, state_file):
    items = inputs_of(walk(seconds=80.0, seed=21))
    path = tmp_path / "inc.mcap"
    live = MiniShell(path, IncidentCore(CFG))
    crash_at = 500
    for i in range(0, crash_at, 10):
        live.round(items[i:i + 10])
    steps_at_crash = live.core.responders["ff1"].tracker.steps
    _crash(live.rec)  # up to the last snapshot and the chunks after it are in the file
    if state_file == "missing":
        state_path(path).unlink()
    elif state_file == "damaged":
        state_path(path).write_bytes(b"\x93garbage")
    res = resume(path, CFG)
    assert res.segment == 1 and res.path == tmp_path / "inc.1.mcap"
    assert res.base.origin == ("state file" if state_file == "kept" else "start")
    assert (state_file == "damaged") == any("cannot be read" in p for p in res.problems)
    r = res.core.responders["ff1"]
    # what the file held is back: every frame released before the last complete chunk
    assert 0 <= steps_at_crash - r.tracker.steps < 15 and r.gate.next_seq <= live.core.responders["ff1"].gate.next_seq
    # the wearable's kept frames come again: those taken already are duplicates, the rest go on
    first = r.gate.next_seq - 30
    second = MiniShell(res.path, res.core, segment=1, resume_record=res.base.record())
    rest = items[1 + first:]
    for i in range(0, len(rest), 10):
        second.round(rest[i:i + 10])
    second.rec.close()
    assert second.core.responders["ff1"].gate.counts == {"duplicate": 30}
    # the same as an uninterrupted run of every frame, step for step, within centimetres
    ref = IncidentCore(CFG)
    ref_poses = poses(ref.feed_round(items))
    assert second.core.responders["ff1"].tracker.steps == ref.responders["ff1"].tracker.steps
    last = [p for p in second.published if isinstance(p, wire.Pose)][-1]
    same = [p for p in ref_poses if p.t == last.t][-1]
    assert math.hypot(last.x - same.x, last.y - same.y) < 1.0
    # reprocess of the segmented recording takes the same path and gives the poses published live
    rp = reprocess(path, CFG)
    assert rp["segments"] == 2 and rp["resumed_segments"] == [1]
    assert rp["max_deviation_m"] == 0.0 and rp["responders"]["ff1"]["unmatched_live_poses"] == 0
    assert rp["responders"]["ff1"]["steps"] == ref.responders["ff1"].tracker.steps


def test_resume_never_refuses_and_starts_afresh_on_a_file_that_is_no_recording(tmp_path):
    path = tmp_path / "inc.mcap"
    path.write_bytes(b"this is not an MCAP file")
    res = resume(path, CFG)
    assert res is not None and res.core.responders == {} and res.path == tmp_path / "inc.1.mcap"
    assert resume(tmp_path / "none.mcap", CFG) is None  # nothing there: a fresh start


def test_a_resume_base_round_trips_through_its_attachment():
    b = Base(3, 1234, b"snap", "state file")
    assert Base.from_record(b.record()) == b


def test_serve_on_an_existing_recording_resumes_instead_of_refusing(tmp_path):
    """The command itself, twice on one recording path (what systemd does after a crash)."""
    from service.protocol.session import free_local_port

    path = tmp_path / "inc.mcap"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    exe = [sys.executable, "-m", "client.entry"]
    for run in range(2):
        ep = f"tcp/127.0.0.1:{free_local_port()}"
        p = subprocess.run([*exe, "serve", "--listen", ep, "--record", str(path), "--no-console", "--seconds", "1"],
                           capture_output=True, text=True, timeout=120, env=env)
        assert p.returncode == 0, p.stderr[-2000:]
        if run == 1:
            assert "resumed incident" in p.stderr and "inc.1.mcap" in p.stderr
    assert [q.name for q in segment_paths(path)] == ["inc.mcap", "inc.1.mcap"]
    time.sleep(0)


def test_bench_resume_resumes_from_the_snapshot_to_the_same_core_as_a_whole_replay(tmp_path):
    """``firetrack bench resume`` at a toy size: the snapshot's way replays only what came after
    it, and both ways give the steps of the live core and about the same last poses (not bit for
    bit: a resumed estimator restarts its graph from the snapshot's newest pose and marginal)."""
    from service.review.resume import bench_resume

    r = bench_resume(responders=2, minutes=0.5, workdir=tmp_path, log=lambda m: None)
    assert r["replayed_after_snapshot"] < r["replayed_from_start"] == r["frames"]
    assert all(a == b == c for a, b, c in r["steps_equal"].values())
    assert all(a > 0 for a, _, _ in r["steps_equal"].values())
    assert r["resumed_cores_apart_m"] < 0.01 and r["snapshot_bytes"]["last"] > 0


def test_a_snapshot_of_an_older_version_restores_with_every_declared_field():
    """A snapshot written before ``Responder.beacons_heard``, the tracker's restart counts and
    the held fixes existed (the fields dropped from its pickles here) restores: the fields read
    as their defaults, Status reads them, and the core goes on."""
    core = IncidentCore(CFG)
    items = inputs_of(walk(seconds=8.0, seed=3))
    core.feed_round(items[:40])
    state = snapshots.loads(core.snapshot())
    fleet = state["fleet"]
    refs = snapshots.SharedRefs(fleet, [state["tracker_settings"]] + ([fleet.settings, fleet.floors] if fleet else []))
    for rid, blob in state["responders"].items():
        fields = snapshots.load_responder(blob, refs)
        del fields["beacons_heard"]
        for old in ("_degraded_before", "_degraded_at_before"):
            del vars(fields["tracker"])[old]
        state["responders"][rid] = snapshots.dump_responder(fields, refs)
    del state["held_fixes"]
    twin = IncidentCore.restore(snapshots.dumps(state), CFG)
    r = twin.responders["ff1"]
    assert r.beacons_heard == {} and r.tracker.degraded == 0 and twin.fixes.held == {}
    st = twin.status_of(r, items[39].received)
    assert st.beacons_heard == {} and "degraded" not in st.fixes
    assert poses(twin.feed_round(items[40:])) == poses(core.feed_round(items[40:]))


def test_a_snapshot_from_before_the_provisional_floor_level_restores():
    """The floor tracker's state rows were 15 numbers wide before a fix on the stairs could leave a
    provisional level (``F_PROV_FROM``): such a snapshot restores with that field empty, and the
    core goes on as the live one does."""
    from pdr.floor_kernels import F_PROV_FROM, F_STATE

    core = IncidentCore(CFG)
    items = inputs_of(walk(seconds=8.0, seed=3))
    core.feed_round(items[:40])
    state = snapshots.loads(core.snapshot())
    rows = state["fleet"].rows
    assert rows.fs.shape[1] == F_STATE == F_PROV_FROM + 1
    rows.fs = rows.fs[:, :F_PROV_FROM].copy()
    rows.layout["fs"] = ((F_PROV_FROM,), "f8", np.nan)
    twin = IncidentCore.restore(snapshots.dumps(state), CFG)
    fs = twin.fleet.rows.fs
    assert fs.shape[1] == F_STATE and np.isnan(fs[:, F_PROV_FROM]).all()
    assert poses(twin.feed_round(items[40:])) == poses(core.feed_round(items[40:]))

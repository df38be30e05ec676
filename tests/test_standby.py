"""A standby that takes over (issue 29, part 4), and the epoch that fences the service it replaced.

A router in its own process (zenohd's role), ``firetrack serve --connect`` as the primary and
``firetrack serve --connect --standby`` beside it, simulated walkers publishing through
wearables (:class:`client.wearable.Wearable`: kept frames, resend on request). Every pose and
status carries the claim of the service that published it (zenoh's attachment), so the test
sees who published what.
"""
from __future__ import annotations

import math
import signal
import subprocess
import sys
import threading
import time

import zenoh

from service.protocol import wire
from service.protocol.incident import default_incident
from service.protocol.session import client_config, free_local_port
from service.shell.standby import Fence
from tests.faults import RouterProcess, reference, walker, walker_frames
from tests.zenoh_util import wait_until

CFG = default_incident()
WALKERS = ("ff1", "ff2")


class Published:
    """Every pose and status of the incident, with the claim that published it and when it came."""

    def __init__(self, session):
        self.items: list[tuple[float, str, object]] = []  # (arrival, claim, Pose | Status)
        self._lock = threading.Lock()
        self._subs = [session.declare_subscriber(wire.key_all(CFG.id, k), self._on) for k in ("pose", "status")]

    def _on(self, sample) -> None:
        att = sample.attachment
        claim = att.to_bytes().decode() if att is not None else ""
        msg = wire.decode(sample.payload.to_bytes())
        with self._lock:
            self.items.append((time.monotonic(), claim, msg))

    def poses(self, rid: str, claim: str | None = None) -> list[wire.Pose]:
        with self._lock:
            return [m for _, c, m in self.items if isinstance(m, wire.Pose) and m.responder == rid
                    and (claim is None or c == claim)]

    def claims(self) -> list[str]:
        """The claims in the order they were first heard."""
        with self._lock:
            return list(dict.fromkeys(c for _, c, _ in self.items))

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


class Serve:
    """``firetrack serve --connect EP --no-console [extra]`` whose output lines are read on a thread."""

    def __init__(self, endpoint: str, *extra: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "client.entry", "serve", "--no-console", "--connect", endpoint,
                                      *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines: list[tuple[float, str]] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append((time.monotonic(), line))

    def said(self, text: str) -> float | None:
        """When a line holding ``text`` was printed (None: not yet)."""
        return next((at for at, line in list(self.lines) if text in line), None)

    def wait_for(self, text: str, timeout: float) -> float:
        assert wait_until(lambda: self.said(text) is not None, timeout, 0.1), \
            f"{text!r} not printed within {timeout} s: {self.output()[-3000:]}"
        return self.said(text)

    def output(self) -> str:
        return "".join(line for _, line in list(self.lines))

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)


def _closest(poses: list[wire.Pose], t: float) -> wire.Pose | None:
    return min(poses, key=lambda p: abs(p.t - t), default=None)


def test_a_standby_takes_over_from_a_killed_primary_within_10_s_and_loses_nothing():
    ep = f"tcp/127.0.0.1:{free_local_port()}"
    router = RouterProcess(ep).start()
    primary = standby = None
    walkers = []
    watch_session = zenoh.open(client_config(ep))
    watch = Published(watch_session)
    try:
        primary = Serve(ep)
        primary.wait_for("serving incident demo", 180)
        standby = Serve(ep, "--standby")
        standby.wait_for("standing by for incident demo", 180)
        walkers = [walker(ep, rid, seed=i + 3, seconds=75.0, speed=3.0).start() for i, rid in enumerate(WALKERS)]
        assert wait_until(lambda: all(watch.poses(r) for r in WALKERS), 60), primary.output()[-3000:]
        time.sleep(10.0)  # a few of the primary's snapshots reach the standby
        primary.proc.send_signal(signal.SIGKILL)
        primary.proc.wait(10)
        killed = time.monotonic()
        first, second = (watch.claims() + [None])[:2]
        taken = standby.wait_for("serving incident demo", 60)
        assert wait_until(lambda: len(watch.claims()) == 2 and all(watch.poses(r, watch.claims()[1]) for r in WALKERS),
                          60), (watch.claims(), standby.output()[-3000:])
        second = watch.claims()[1]
        first_pose = min(at for at, c, m in watch.items if c == second and isinstance(m, wire.Pose))
        for w in walkers:
            assert w.done.wait(120)
        reports = {w.responder: w.close(30.0) for w in walkers}
        walkers = []
        statuses = {}
        for at, c, m in watch.items:
            if isinstance(m, wire.Status):
                statuses.setdefault(m.responder, []).append((at, c, m))
        standby.proc.send_signal(signal.SIGINT)
        assert standby.proc.wait(60) == 0, standby.output()[-3000:]
    finally:
        for w in walkers:
            w.close(0.0)
        for s in (primary, standby):
            if s is not None:
                s.kill()
        watch.close()
        watch_session.close()
        router.stop()
    out = standby.output()
    print(f"\nFIGURE standby takeover: serving {taken - killed:.1f} s and first pose {first_pose - killed:.1f} s "
          f"after SIGKILL; claims {first} -> {second}; wearables {reports}")
    assert "taking over from the snapshot of epoch 1." in out, out[-3000:]
    assert first.startswith("1.") and second.startswith("2."), (first, second)
    assert first_pose - killed <= 10.0, first_pose - killed  # the standby publishes within 10 s
    for rid, w_report in reports.items():
        said_lost = [line for line in out.splitlines() if " lost: " in line]  # the gate's reason, when it gave up
        assert w_report["unacknowledged"] == 0 and w_report["service_lost"] == 0, (rid, w_report, said_lost[-10:])
        mine = statuses[rid]
        # never two publishers: the first claim's messages all came before the second's first
        last_first = max(at for at, c, _ in mine if c == first)
        first_second = min(at for at, c, _ in mine if c == second)
        assert last_first < first_second, rid
        assert not any(wire_alarm == "man_down" for _, _, m in mine for wire_alarm in m.alarms), rid  # no false man-down
        assert mine[-1][2].lost == 0, (rid, mine[-1][2])
        # the track as an uninterrupted run makes it (every frame once, in order), within 1 m
        ref, _ = reference(CFG, rid, walker_frames(rid, 75.0, WALKERS.index(rid) + 3))
        last = watch.poses(rid, second)[-1]
        twin = _closest(ref, last.t)
        assert twin is not None and abs(twin.t - last.t) < 1e-6, (last.t, twin and twin.t)
        assert math.hypot(last.x - twin.x, last.y - twin.y) < 1.0, (rid, last, twin)


def test_a_primary_that_sees_a_higher_epoch_stands_down_and_publishes_no_more():
    """The returning old primary: while it serves, a service of a higher epoch claims its part
    (here a claim made by the test, as a standby that took over during a partition would). The
    primary stops publishing at once and exits with code 3."""
    ep = f"tcp/127.0.0.1:{free_local_port()}"
    router = RouterProcess(ep).start()
    session = zenoh.open(client_config(ep))
    watch = Published(session)
    primary = w = fence = None
    try:
        primary = Serve(ep)
        primary.wait_for("serving incident demo", 180)
        w = walker(ep, "ff1", seed=2, seconds=60.0, speed=2.0).start()
        assert wait_until(lambda: len(watch.poses("ff1")) >= 3, 60), primary.output()[-3000:]
        (old,) = watch.claims()
        fence = Fence(session, CFG.id, (0, 1))
        assert fence.claim() == int(old.split(".")[0]) + 1
        claimed = time.monotonic()
        stood = primary.wait_for("stood down: the service of epoch 2", 30)
        assert primary.proc.wait(30) == 3, primary.output()[-3000:]
        time.sleep(1.0)
        last_old = max(at for at, c, _ in watch.items if c == old)
    finally:
        if w is not None:
            w.close(0.0)
        if fence is not None:
            fence.close()
        if primary is not None:
            primary.kill()
        watch.close()
        session.close()
        router.stop()
    print(f"\nFIGURE stand down: last message of epoch {old} {last_old - claimed:+.3f} s after epoch 2 was claimed; "
          f"'stood down' {stood - claimed:.2f} s after")
    assert last_old - claimed < 0.5, last_old - claimed  # what was in flight when the claim came, no more

"""Simulated responders on the wire: ``firetrack simulate --responders N [--seconds S] [--rate HZ]``.

A :class:`pdr.simulation.WalkerFleet` walks N responders through the incident's building;
every ``1/frames_per_s`` of wall time each walker's new samples leave as one
:class:`service.protocol.wire.ImuBatch` on ``.../imu``, and its true position as a small msgpack map
on ``.../truth`` (``{"t", "x", "y", "floor", "heading", "steps"}`` — for scoring and the
console, never read by the service). Each walker first sends a checkpoint fix at its start
point: the door it came in by.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping

import msgpack
import numpy as np
import zenoh

from client.wearable import KEEP_FRAMES, Wearable
from pdr.simulation import WalkerFleet, WalkerSettings
from service.protocol import wire
from service.protocol.messages import FRAMES_PER_SECOND


def building_bounds(incident, margin: float = 5.0) -> tuple[float, float, float, float]:
    """Where simulated walkers roam: around the incident's checkpoints (or 40 x 20 m at the origin)."""
    if incident is not None and incident.checkpoints:
        x = np.array([c.x for c in incident.checkpoints])
        y = np.array([c.y for c in incident.checkpoints])
        x0, x1, y0, y1 = x.min() - margin, x.max() + margin, y.min() - margin, y.max() + margin
        if x1 - x0 >= 10 and y1 - y0 >= 10:
            return float(x0), float(x1), float(y0), float(y1)
    return (-20.0, 20.0, -10.0, 10.0)


SIM_KEEP_FRAMES = 100  # frames each simulated wearable keeps in zenoh's keep (10 s at 10 frames/s: many in one
# process); precomputed frames (the benchmark's) are also kept as a real wearable keeps them (PrecomputedKeep)


class BootStreams:
    """Which simulated wearers have a boot-mounted IMU, and its signals.

    A share ``foot`` of the walkers (the first ``round(foot·n)``) wear the IMU on the boot
    (``carry="foot"``): their frames carry a synthetic boot IMU's accelerometer and gyroscope
    (:func:`pdr.zupt.synthetic.foot_walk`: strides of 1.2-1.4 m with turns, 0.45 s stance and
    0.65 s swing, with sensor noise) and no magnetometer or barometer, as a boot unit has none.
    The rest are handhelds with the walker fleet's phone signals. A few distinct walks are made
    once and shared (walker i takes walk i mod ``WALKS``, looping): the service cannot tell,
    and the load generator stays cheap. The fleet's times are kept, so the frames are paced as
    the handhelds' are.
    """

    WALKS = 4

    def __init__(self, n: int, foot: float, rate_hz: float, start_t: float, seed: int):
        if not 0.0 <= foot <= 1.0:
            raise ValueError(f"foot is the share of boot-mounted wearers, 0..1; got {foot}")
        self.count = int(round(foot * n))
        self._walks = []
        if self.count:
            from pdr.zupt.synthetic import foot_walk

            rng = np.random.default_rng([seed, 0xB007])
            for w in range(min(self.WALKS, self.count)):
                strides = [(float(rng.uniform(1.2, 1.4)), float(rng.normal(0.0, 0.15)), 0.0) for _ in range(300)]
                walk = foot_walk(strides, rate_hz=rate_hz, yaw0=float(rng.uniform(-np.pi, np.pi)), acc_noise=0.02,
                                 gyr_noise=0.002, seed=seed * 101 + w, t0=start_t)
                self._walks.append((walk.acc, walk.gyr))
        self._cursor = np.zeros(self.count, dtype=np.int64)

    def signals(self, i: int, b) -> dict:
        """The ImuBatch fields of walker ``i``'s batch ``b`` other than its times."""
        if i >= self.count:
            p_t = b.pressure_t if len(b.pressure_t) else None
            p_v = b.pressure if len(b.pressure_t) else None
            return {"acc": b.acc, "gyr": b.gyr, "mag": b.mag, "pressure_t": p_t, "pressure": p_v, "carry": "handheld"}
        acc, gyr = self._walks[i % len(self._walks)]
        idx = (self._cursor[i] + np.arange(len(b.t))) % len(acc)
        self._cursor[i] += len(b.t)
        return {"acc": acc[idx], "gyr": gyr[idx], "carry": "foot"}


class PrecomputedKeep(Mapping):
    """Walker ``i``'s keep of the frames :meth:`SimulationPublisher.precompute` made: seq ->
    encoded frame for the newest ``keep`` of those already sent (``next_seq[i]``, the publisher's
    own counter, says how far it got). A view of the precomputed table, not a copy: a thousand
    wearables keep 5 minutes each as a real one does (:data:`client.wearable.KEEP_FRAMES`) at no
    cost in memory beyond the table the run holds anyway."""

    def __init__(self, frames: list[list[bytes]], i: int, seq0: int, next_seq: np.ndarray, keep: int):
        self.frames, self.i, self.seq0, self.next_seq, self.keep = frames, i, seq0, next_seq, keep

    def _window(self) -> range:
        sent = min(int(self.next_seq[self.i]), self.seq0 + len(self.frames))
        return range(max(self.seq0, sent - self.keep), sent)

    def __getitem__(self, seq: int) -> bytes:
        if seq not in self._window():
            raise KeyError(seq)
        return self.frames[seq - self.seq0][self.i]

    def __iter__(self):
        return iter(self._window())

    def __len__(self) -> int:
        return len(self._window())


# WalkerSettings of a drill crew: every wearer keeps walking at one cadence (no pauses, no stairs, corners walked
# through), so each takes the same steps per second and any spread of the service's pose rates is the service's
DRILL_CREW = {"pause_probability": 0.0, "cadence_jitter": 0.0, "cadence_leg_jitter": 0.0, "stairs_probability": 0.0,
              "max_walking_turn_rad": math.pi}


class SimulationPublisher:
    """N simulated wearables on one zenoh session, advanced one frame at a time."""

    def __init__(self, session: zenoh.Session, incident_id: str, n: int, rate_hz: float = 100.0, seed: int = 0,
                 bounds=None, floors=(0, 0), prefix: str = "sim", truth: bool = True, start_t: float = 1000.0,
                 start_spread_s: float = 0.0, foot: float = 0.0, keep_frames: int = SIM_KEEP_FRAMES,
                 drill: bool = False):
        self.session = session
        self.incident_id = incident_id
        self.rate_hz = rate_hz
        self.names = [f"{prefix}-{i:03d}" for i in range(n)]
        settings = WalkerSettings(rate_hz=rate_hz, **(DRILL_CREW if drill else {}))
        kw = {} if bounds is None else {"bounds": bounds}
        self.fleet = WalkerFleet(n, settings, seed, responders=self.names, floors=floors, start_t=start_t,
                                 attitude=False, **kw)
        if start_spread_s > 0:  # crews do not start walking in the same instant: each waits a while first
            waits = np.random.default_rng([seed, 0x5747]).uniform(0.0, start_spread_s, n)
            for i, w in enumerate(waits):
                self.fleet.stand_still(i, float(w), at=start_t)
        # each keeps its last keep_frames frames to resend (10 s by default: many walkers in one process)
        self.wearables = [Wearable(session, incident_id, r, keep_frames=keep_frames) for r in self.names]
        self.seq = np.zeros(n, dtype=np.int64)
        self.boots = BootStreams(n, foot, rate_hz, start_t, seed)
        self.truth = truth
        self.started = False

    def step(self, samples: int, on_frame: Callable[[int, int, float], None] | None = None) -> int:
        """Publish the next ``samples`` samples of every walker; returns the frames sent."""
        batches = self.fleet.next_batches(samples)
        self._publish(batches, range(len(batches)), on_frame)
        self.started = True
        return len(batches)

    def _publish(self, batches, which, on_frame) -> None:
        for i in which:
            w, b = self.wearables[i], batches[i]
            if not self.started:  # the door it came in by
                w.send("fix", wire.Fix.checkpoint(w.responder, float(b.t[0]), x=float(b.x[0]), y=float(b.y[0]),
                                                  floor=int(b.floor[0]), sigma=0.3, operator="simulator"))
            msg = wire.ImuBatch(responder=w.responder, device=f"sim:{w.responder}", seq=int(self.seq[i]), t=b.t,
                                utc_offset=time.time() - float(b.t[-1]), **self.boots.signals(i, b))
            w.send("imu", msg)
            if on_frame is not None:
                on_frame(i, int(self.seq[i]), time.time())
            self.seq[i] += 1
            if self.truth:
                w.send("truth", msgpack.packb({"t": float(b.t[-1]), "x": float(b.x[-1]), "y": float(b.y[-1]),
                                               "floor": int(b.floor[-1]), "heading": float(b.heading[-1]),
                                               "steps": int(b.step_count[-1])}))

    def stand_still(self, i: int, seconds: float) -> None:
        self.fleet.stand_still(i, seconds)

    def collapse(self, i: int) -> None:
        self.fleet.collapse(i)

    def run(self, seconds: float, stop: threading.Event | None = None, frames_per_s: float = FRAMES_PER_SECOND,
            on_frame=None, on_tick: Callable[[float], None] | None = None, slices: int = 10) -> int:
        """Publish in real time for ``seconds`` (device time advances with the wall clock).

        Real wearables are not synchronised: each sends its frame at its own phase of the frame
        period. The walkers are therefore published in ``slices`` groups spread evenly over
        each period rather than all at one instant (``slices=1`` is that worst case).
        """
        per = max(1, int(round(self.rate_hz / frames_per_s)))
        period = per / self.rate_hz
        ticks = int(round(seconds / period))
        n = len(self.wearables)
        g = max(1, min(slices, n))
        groups = [range(j * n // g, (j + 1) * n // g) for j in range(g)]
        start = time.monotonic()
        sent = 0
        for k in range(ticks):
            batches = self.fleet.next_batches(per)
            for j, group in enumerate(groups):
                if not self._wait(start + (k + j / len(groups)) * period, stop):
                    return sent
                self._publish(batches, group, on_frame)
            self.started = True
            sent += len(batches)
            if on_tick is not None:
                on_tick((k + 1) * period)
        self._wait(start + ticks * period, stop)
        return sent

    def precompute(self, seconds: float, frames_per_s: float = FRAMES_PER_SECOND) -> list[list[bytes]]:
        """Every walker's frames for the next ``seconds``, encoded now: ``frames[k][i]`` is walker
        i's k-th frame (seq continuing from what was sent). A load generator that publishes them
        with :meth:`run_precomputed` costs a ``put`` per frame, not a simulation and an encoding,
        so at a thousand wearables it is not the bottleneck it measures. The clock offset each
        frame carries is the one of this moment (device time advances with the wall clock)."""
        per = max(1, int(round(self.rate_hz / frames_per_s)))
        ticks = int(round(seconds * self.rate_hz / per))
        offset: list[float | None] = [None] * len(self.wearables)
        out: list[list[bytes]] = []
        for k in range(ticks):
            row = []
            for i, b in enumerate(self.fleet.next_batches(per)):
                if offset[i] is None:
                    offset[i] = time.time() - float(b.t[0])
                r = self.wearables[i].responder
                row.append(wire.encode(wire.ImuBatch(responder=r, device=f"sim:{r}", boot=self.wearables[i].boot,
                                                     seq=int(self.seq[i]) + k, t=b.t, utc_offset=offset[i],
                                                     **self.boots.signals(i, b))))  # as Wearable.send stamps it
            out.append(row)
        for i, w in enumerate(self.wearables):  # each keeps what it sent of them, as Wearable.send would
            w.keep_sent(PrecomputedKeep(out, i, int(self.seq[i]), self.seq, KEEP_FRAMES))
        return out

    def run_precomputed(self, frames: list[list[bytes]], stop: threading.Event | None = None,
                        frames_per_s: float = FRAMES_PER_SECOND, on_frame=None, slices: int = 10) -> int:
        """Publish :meth:`precompute`'s frames in real time, each walker at its own phase of the
        frame period (as :meth:`run`); returns the frames sent."""
        per = max(1, int(round(self.rate_hz / frames_per_s)))
        period = per / self.rate_hz
        n = len(self.wearables)
        g = max(1, min(slices, n))
        groups = [range(j * n // g, (j + 1) * n // g) for j in range(g)]
        pubs = [w._pub["imu"] for w in self.wearables]
        start = time.monotonic()
        sent = 0
        for k, row in enumerate(frames):
            for j, group in enumerate(groups):
                if not self._wait(start + (k + j / len(groups)) * period, stop):
                    return sent
                for i in group:
                    pubs[i].put(row[i])
                    if on_frame is not None:
                        on_frame(i, int(self.seq[i]), time.time())
                    self.seq[i] += 1
                sent += len(group)
        self._wait(start + len(frames) * period, stop)
        return sent

    @staticmethod
    def _wait(until: float, stop: threading.Event | None) -> bool:
        """Sleep until ``until`` (monotonic); False when asked to stop."""
        wait = until - time.monotonic()
        if stop is not None:
            return not (stop.is_set() or (wait > 0 and stop.wait(wait)))
        if wait > 0:
            time.sleep(wait)
        return True

    def close(self) -> None:
        for w in self.wearables:
            w.close()

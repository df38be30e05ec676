"""Fault injection on loopback: a TCP link that can be cut, a router in its own process, walkers
that publish simulated frames as wearables do (in a thread, or in a process that can be killed).

``python -m tests.faults walker ENDPOINT INCIDENT RESPONDER SEED SECONDS SPEED [--skip N]`` runs
one walker wearable in its own process (what ``test_faults`` kills with SIGKILL).
"""
from __future__ import annotations

import math
import select
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

import zenoh

from client.wearable import Wearable
from service.core.incident_core import Inbound, IncidentCore
from service.protocol import wire
from service.protocol.session import client_config
from tests.walkers import restamped, walk


class TcpProxy:
    """Forwards ``127.0.0.1:port`` to a target port. :meth:`cut` closes every connection and
    refuses new ones (a Wi-Fi outage: the wearable's zenoh session loses its router);
    :meth:`restore` lets connections through again."""

    def __init__(self, target_port: int):
        self.target = ("127.0.0.1", target_port)
        self._l = socket.socket()
        self._l.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._l.bind(("127.0.0.1", 0))
        self._l.listen(16)
        self.port = self._l.getsockname()[1]
        self.up = True
        self._conns: list[tuple[socket.socket, socket.socket]] = []
        self._lock = threading.Lock()
        self._closed = False
        threading.Thread(target=self._accept, daemon=True, name="proxy-accept").start()

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    def _accept(self) -> None:
        while not self._closed:
            try:
                c, _ = self._l.accept()
            except OSError:
                return
            if not self.up:
                c.close()
                continue
            try:
                s = socket.create_connection(self.target, timeout=2.0)
            except OSError:
                c.close()
                continue
            with self._lock:
                self._conns.append((c, s))
            threading.Thread(target=self._pump, args=(c, s), daemon=True, name="proxy-pump").start()

    @staticmethod
    def _pump(a: socket.socket, b: socket.socket) -> None:
        try:
            while True:
                ready, _, _ = select.select([a, b], [], [], 0.2)
                for x in ready:
                    data = x.recv(65536)
                    if not data:
                        raise OSError("closed")
                    (b if x is a else a).sendall(data)
        except OSError:
            pass
        finally:
            for x in (a, b):
                try:
                    x.close()
                except OSError:
                    pass

    def cut(self) -> None:
        self.up = False
        with self._lock:
            for pair in self._conns:
                for x in pair:
                    try:
                        x.shutdown(socket.SHUT_RDWR)
                    except OSError:
                        pass
            self._conns.clear()

    def restore(self) -> None:
        self.up = True

    def close(self) -> None:
        self._closed = True
        self.cut()
        self._l.close()


ROUTER_CODE = """
import signal, sys, zenoh
from service.protocol.session import router_config
s = zenoh.open(router_config([sys.argv[1]]))
print("up", flush=True)
signal.sigwait([signal.SIGTERM, signal.SIGINT])
"""


class RouterProcess:
    """A zenoh router in its own process on ``endpoint`` (a standalone router: zenohd's role)."""

    def __init__(self, endpoint: str):
        self.endpoint = endpoint
        self.proc: subprocess.Popen | None = None

    def start(self) -> RouterProcess:
        self.proc = subprocess.Popen([sys.executable, "-c", ROUTER_CODE, self.endpoint], stdout=subprocess.PIPE,
                                     text=True)
        line = self.proc.stdout.readline()
        if line.strip() != "up":
            raise RuntimeError(f"the router on {self.endpoint} did not start")
        return self

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(10)


@dataclass
class WalkerWearable:
    """A simulated walker published by a :class:`client.wearable.Wearable` on its own zenoh
    session at ``speed`` times real time, in a thread. ``sent_at[seq]`` is when frame ``seq``
    left (the service's clock is this machine's too: latency = ``published_at - sent_at``)."""

    endpoint: str
    incident: str
    responder: str
    seed: int = 0
    seconds: float = 60.0
    speed: float = 1.0
    boot: str | None = None
    frames: list = field(default_factory=list)
    sent_at: dict = field(default_factory=dict)
    report: dict | None = None

    def __post_init__(self):
        self.walk = walk(self.responder, seconds=self.seconds, seed=self.seed, boot=None)
        self.frames = self.walk.frames
        self.stop = threading.Event()
        self.done = threading.Event()
        self.session = zenoh.open(client_config(self.endpoint))
        self.wearable = Wearable(self.session, self.incident, self.responder, boot=self.boot)
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"walker-{self.responder}")

    def start(self) -> WalkerWearable:
        self._thread.start()
        return self

    def _run(self) -> None:
        period = 0.1 / self.speed
        t0 = time.monotonic()
        for k, f in enumerate(self.frames):
            if self.stop.is_set():
                break
            wait = t0 + k * period - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            self.sent_at[f.seq] = time.time()
            self.wearable.send("imu", f)
        self.done.set()

    def sent(self) -> int:
        return len(self.sent_at)

    def close(self, flush_s: float = 10.0) -> dict:
        self.stop.set()
        self._thread.join(30)
        self.report = self.wearable.close(flush_s)
        self.session.close()
        return self.report


def reference(incident, responder: str, frames) -> tuple[list[wire.Pose], IncidentCore]:
    """The uninterrupted run: every frame once, in order, through a core of its own."""
    core = IncidentCore(incident)
    k = wire.key(incident.id, responder, "imu")
    out = core.feed_round([Inbound("imu", k, wire.encode(f), 1000.0 + i * 0.1) for i, f in enumerate(frames)])
    return [o.message for o in out if isinstance(o.message, wire.Pose)], core


def percentile(values, q: float) -> float:
    if not values:
        return math.nan
    v = sorted(values)
    return v[min(len(v) - 1, int(math.ceil(q / 100.0 * len(v))) - 1)]


def _walker_main(argv: list[str]) -> None:  # pragma: no cover - runs in a child process
    endpoint, incident, responder, seed, seconds, speed = argv[:6]
    skip = int(argv[argv.index("--skip") + 1]) if "--skip" in argv else 0
    w = WalkerWearable(endpoint, incident, responder, int(seed), float(seconds), float(speed))
    if skip:  # a restarted wearable: the walk goes on, its counter starts again (and its boot is new)
        w.frames = restamped(w.frames[skip:], seq0=0)
    print("ready", flush=True)
    w.start()
    w.done.wait()
    print("sent", w.sent(), flush=True)
    w.close(5.0)


if __name__ == "__main__":  # pragma: no cover
    if sys.argv[1] == "walker":
        _walker_main(sys.argv[2:])

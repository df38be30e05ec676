"""Fault injection on loopback: a TCP link that can be cut and walker wearables
(:mod:`client.fault_bench`), a router in its own process, a walker in a process that can be killed.

``python -m tests.faults walker ENDPOINT INCIDENT RESPONDER SEED SECONDS SPEED [--skip N]`` runs
one walker wearable in its own process (what ``test_faults`` kills with SIGKILL).
"""
from __future__ import annotations

import math
import subprocess
import sys

from client.faults_loopback import TcpProxy, WalkerWearable, hostile_messages, walker_frames  # noqa: F401
from service.core.incident_core import Inbound, IncidentCore
from service.protocol import wire
from tests.walkers import restamped


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


def walker(endpoint: str, responder: str, seed: int = 0, seconds: float = 60.0, speed: float = 1.0,
           incident: str = "demo", zenoh_keep: bool = True, tls=None) -> WalkerWearable:
    """A simulated walker's frames published by a wearable at ``speed`` times real time (with
    ``tls``, a :class:`~service.protocol.tls.TlsIdentity`, over mutual TLS as that identity)."""
    return WalkerWearable(endpoint, incident, responder, walker_frames(responder, seconds, seed), speed,
                          zenoh_keep=zenoh_keep, tls=tls)


def shut_down(walkers=(), proxies=(), *others) -> None:
    """The end of a fault test: the walkers not closed yet (without waiting), the proxies, then
    each of ``others`` (watchers, services, sessions) in order."""
    for w in walkers:
        if w.report is None:
            w.close(0.0)
    for p in proxies:
        p.close()
    for o in others:
        o.close()


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
    w = walker(endpoint, responder, int(seed), float(seconds), float(speed), incident)
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

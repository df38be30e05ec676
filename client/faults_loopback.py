"""Faults on loopback, for the fault bench (:mod:`client.fault_bench`) and the fault-injection
tests (``tests/test_faults.py``): a TCP link that can be cut (:class:`TcpProxy`), simulated
walkers' frames and a walker wearable in a thread (:class:`WalkerWearable`), and the hostile
messages an attacker publishes (:func:`hostile_messages`, :func:`fresh_id_messages`)."""
from __future__ import annotations

import select
import socket
import threading
import time

import msgpack
import numpy as np
import zenoh

from client.wearable import Wearable
from service.protocol import wire
from service.protocol.session import client_config


class TcpProxy:
    """Forwards ``127.0.0.1:port`` to a target port. :meth:`cut` closes every connection and
    refuses new ones (a Wi-Fi outage: a wearable's zenoh session loses its router);
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


def walker_frames(responder: str, seconds: float, seed: int, t0: float = 1000.0, rate_hz: float = 100.0,
                  bounds=(-30.0, 30.0, -20.0, 20.0)) -> list[wire.ImuBatch]:
    """``seconds`` of a simulated walker (a random route in ``bounds``) as 10 frames/s."""
    from pdr.simulation import SimulatedWalker, WalkerSettings

    w = SimulatedWalker(responder, None, WalkerSettings(rate_hz=rate_hz), seed, start_t=t0, bounds=bounds,
                        floors=(0, 0), attitude=False)
    b = w.next_batch(int(round(seconds * rate_hz)))
    return list(wire.imu_batches_from_arrays(responder, "phone-1", b.t, b.acc, b.gyr, b.mag, b.pressure_t,
                                             b.pressure, carry="handheld", per_batch=int(round(rate_hz / 10))))


class WalkerWearable:
    """Frames published by a :class:`client.wearable.Wearable` on its own zenoh session at
    ``speed`` times real time, in a thread. ``sent_at[seq]`` is when frame ``seq`` left; with
    ``tls`` (a :class:`~service.protocol.tls.TlsIdentity`) over mutual TLS as that identity."""

    def __init__(self, endpoint: str, incident: str, responder: str, frames: list, speed: float = 1.0,
                 boot: str | None = None, zenoh_keep: bool = True, tls=None):
        self.responder, self.frames, self.speed = responder, frames, speed
        self.sent_at: dict[int, float] = {}
        self.report: dict | None = None
        self.stop = threading.Event()
        self.done = threading.Event()
        self.session = zenoh.open(client_config(endpoint, tls))
        self.wearable = Wearable(self.session, incident, responder, boot=boot, zenoh_keep=zenoh_keep)
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"walker-{responder}")

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


def hostile_messages(n: int, incident: str, honest: str, seed: int = 0) -> list[tuple[str, bytes]]:
    """``n`` hostile (key, payload) pairs, ten kinds in turn: random bytes, wrong types, NaN,
    repeated and backwards frames (one in a hundred a map nested 100 k deep, one in a thousand
    over the size limit), bad fixes — on the honest responder's key —, a 2,000-character id, a
    fresh id every time, a list for a map, fixes of random bytes from 50 other ids, a schema
    version from the future."""
    rng = np.random.default_rng(seed)
    z = np.zeros((10, 3))
    nan = wire.ImuBatch(responder=honest, device="evil", seq=1, t=np.arange(10) * 0.01, acc=z, gyr=z).to_wire()
    acc = np.frombuffer(nan["acc"], "<f8").copy()
    acc[3] = np.nan
    nan["acc"] = acc.tobytes()
    nan_payload = msgpack.packb(nan, use_bin_type=True)
    deep = b"\x81\xa1a" * 100_000 + b"\xc0"
    big = b"\x00" * (wire.MAX_PAYLOAD_BYTES + 10)
    dup = wire.encode(wire.ImuBatch(responder=honest, device="phone", seq=0, t=np.arange(10) * 0.01, acc=z, gyr=z))
    badfix = msgpack.packb({"v": 1, "kind": "fix", "responder": honest, "t": "soon", "source": "gnss", "lat": 91})
    future = msgpack.packb({"v": 99, "kind": "imu"})

    def k(rid, kind="imu"):
        return f"firetrack/{incident}/{rid}/{kind}"

    out = []
    for i in range(n):
        c = i % 10
        if c == 0:
            out.append((k(honest), rng.bytes(64)))
        elif c == 1:
            out.append((k(honest), msgpack.packb({"v": 1, "kind": "imu", "responder": honest, "seq": "x", "t": [1]})))
        elif c == 2:
            out.append((k(honest), nan_payload))
        elif c == 3:
            out.append((k(honest), big if i % 1000 == 3 else deep if i % 100 == 3 else dup))
        elif c == 4:
            out.append((k(honest, "fix"), badfix))
        elif c == 5:
            out.append((k("x" * 2000), dup))
        elif c == 6:
            out.append((k(f"fresh{i}"), dup))
        elif c == 7:
            out.append((k(honest), msgpack.packb(list(range(50)))))
        elif c == 8:
            out.append((k(f"r{i % 50}", "fix"), rng.bytes(32)))
        else:
            out.append((k(honest), future))
    return out


def fresh_id_messages(n: int, incident: str) -> list[tuple[str, bytes]]:
    """One valid frame from each of ``n`` new responder ids."""
    z = np.zeros((10, 3))
    z[:, 2] = 9.81
    out = []
    for i in range(n):
        rid = f"new{i:05d}"
        b = wire.ImuBatch(responder=rid, device="d", seq=0, t=np.arange(10) * 0.01, acc=z, gyr=np.zeros((10, 3)))
        out.append((f"firetrack/{incident}/{rid}/imu", wire.encode(b)))
    return out

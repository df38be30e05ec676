"""A phone in the test's Chromium: the wearable page (/wear) enrolled through the console,
its motion sensors and position driven by the DevTools protocol's overrides."""
from __future__ import annotations

import contextlib
import json
import urllib.error
import urllib.request

SENSORS = ("accelerometer", "gyroscope", "magnetometer")
SENSOR_FLAGS = ("--enable-features=GenericSensorExtraClasses",  # Magnetometer is behind this flag in Chromium
                # a headless page is a background page to Chromium: its timers and renderer must keep pace
                "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                "--disable-backgrounding-occluded-windows")
PAGE_TIMEOUT_MS = 15_000


def post(url: str, body: dict, origin: str) -> tuple[int, dict]:
    req = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                 headers={"Content-Type": "application/json", "Origin": origin})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read() or b"{}")


def enrol(console_url: str, responder: str) -> dict:
    """An operator enrols a phone for ``responder`` (the demo console: no login)."""
    base = console_url.rstrip("/")
    status, body = post(base + "/api/phones", {"responder": responder}, base)
    assert status == 201, body
    return body


class Phone:
    """A browser tab on /wear with overridden sensors; ``reading(type, x, y, z)`` sets one."""

    def __init__(self, browser, console_url: str, code: str, geolocation: dict | None = None):
        base = console_url.rstrip("/")
        self.context = browser.new_context(viewport={"width": 412, "height": 915}, device_scale_factor=1,
                                           is_mobile=True, has_touch=True, geolocation=geolocation)
        self.context.grant_permissions(["accelerometer", "gyroscope", "magnetometer", "geolocation"], origin=base)
        self.page = self.context.new_page()
        self.errors: list[str] = []
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.cdp = self.context.new_cdp_session(self.page)
        for typ in SENSORS:
            self.cdp.send("Emulation.setSensorOverrideEnabled",
                          {"enabled": True, "type": typ,
                           "metadata": {"available": True, "minimumFrequency": 1, "maximumFrequency": 60}})
        self.page.goto(f"{base}/wear#code={code}")
        self.wait("window.__wear && window.__wear.ready && window.__wear.link && window.__wear.link.ready")

    def reading(self, typ: str, x: float, y: float, z: float) -> None:
        self.cdp.send("Emulation.setSensorOverrideReadings", {"type": typ, "reading": {"xyz": {"x": x, "y": y, "z": z}}})

    def still(self) -> None:
        """A phone lying face up: gravity on z, no rotation, a field pointing north and down."""
        self.reading("accelerometer", 0.0, 0.0, 9.81)
        self.reading("gyroscope", 0.0, 0.0, 0.0)
        self.reading("magnetometer", 0.0, 20.0, -40.0)

    def start(self, carry: str = "hand") -> None:
        self.page.click(f"#carry button[data-carry={carry}]")
        self.page.click("#start")
        self.wait("window.__wear.tracking")

    def js(self, expression: str, arg=None):
        return self.page.evaluate(expression, arg)

    def wait(self, expression: str, arg=None, timeout_ms: int = PAGE_TIMEOUT_MS):
        return self.page.wait_for_function(expression, arg=arg, timeout=timeout_ms)

    def close(self) -> None:
        self.context.close()
        assert self.errors == [], f"errors on the page: {self.errors}"


TURN_S = 0.005  # s between two settings of the accelerometer and gyroscope (the browser samples at 60 Hz)


class Feed:
    """Plays a recording's motion samples into the phone's sensor overrides at the recording's
    own pace: at wall time ``w`` the accelerometer and gyroscope read the recording's signal
    interpolated at file time ``f0 + (w - w0)``, set again every :data:`TURN_S` (or as fast as
    the DevTools protocol takes it), so that whenever the browser samples them (its own rate and
    jitter, as a phone's sensors are sampled) the reading is a few ms old at most; the
    magnetometer the newest sample every ``mag_every_s``. GNSS fixes become geolocation
    overrides at their times. ``w0`` (Unix s) maps back: file time = UTC - w0 + f0."""

    def __init__(self, phone: Phone, rec, f0: float, f1: float, mag_every_s: float = 0.1):
        self.phone, self.rec, self.f0, self.f1, self.mag_every_s = phone, rec, f0, f1, mag_every_s
        self.calls = 0
        self.fixes_set = 0
        self.stalls: list[tuple[float, float]] = []  # (when, s) of each loop turn over 0.1 s (this process held up)

    def run(self) -> None:
        import time

        import numpy as np
        rec, p = self.rec, self.phone

        def at(s, f):
            return [float(np.interp(f, s.t, s.values[:, k])) for k in range(3)]
        mag_at = -np.inf
        gnss = rec.gnss
        g_next = 0 if gnss is None else int(np.searchsorted(gnss.t, self.f0))
        self.w0, self.w0m = time.time(), time.monotonic()
        turn = last_set = self.w0m
        while True:
            now = time.monotonic()
            if now - turn > 0.1:
                self.stalls.append((now - self.w0m, now - turn))
            turn = now
            f = self.f0 + (time.time() - self.w0)
            if f > self.f1:
                break
            if now - last_set < TURN_S:  # every override loads the browser too: no faster than it needs
                time.sleep(TURN_S - (now - last_set))
                continue
            last_set = now
            p.reading("accelerometer", *at(rec.acc, f))
            p.reading("gyroscope", *at(rec.gyr, f))
            self.calls += 2
            if rec.mag is not None and f - mag_at >= self.mag_every_s:
                i = max(int(np.searchsorted(rec.mag.t, f, side="right")) - 1, 0)
                p.reading("magnetometer", *(float(v) for v in rec.mag.values[i]))
                mag_at = f
                self.calls += 1
            while gnss is not None and g_next < len(gnss) and gnss.t[g_next] <= f:
                p.cdp.send("Emulation.setGeolocationOverride", {
                    "latitude": float(gnss.lat[g_next]), "longitude": float(gnss.lon[g_next]),
                    "accuracy": float(gnss.accuracy_m[g_next])})
                g_next += 1
                self.fixes_set += 1


def collect(session, key) -> tuple[list, object]:
    """Every message on ``key`` decoded, as it comes (and the subscriber, to undeclare)."""
    import threading

    from service.protocol import wire
    items, lock = [], threading.Lock()

    def on(sample):
        with lock:
            items.append(wire.decode(sample.payload.to_bytes()))
    return items, session.declare_subscriber(key, on)


class Served:
    """``firetrack serve`` in a process of its own: ``url`` (its console), ``client`` (a zenoh
    session on its router), ``cfg``; :meth:`stop` ends it as an operator does (SIGINT)."""

    def __init__(self, proc, url, client, cfg, log):
        self.proc, self.url, self.client, self.cfg, self.log = proc, url, client, cfg, log

    def stop(self) -> int:
        import signal
        import subprocess
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        return self.proc.returncode


@contextlib.contextmanager
def serving(tmp_path, *args: str):
    """``firetrack serve`` (router, service, console; ``args`` beyond the ports, e.g.
    ``--record x.mcap``) in a process of its own, so that the test's process (the sensor
    feed) shares its interpreter with nothing but zenoh's callbacks."""
    import subprocess
    import sys

    from service.protocol.incident import default_incident
    from tests.zenoh_util import client, free_port, wait_until
    port, web = free_port(), free_port()
    log = tmp_path / "serve.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "client.entry", "serve", "--listen", f"tcp/127.0.0.1:{port}",
                                 "--port", str(web), *args], stdout=out, stderr=subprocess.STDOUT, text=True)
    srv = Served(proc, f"http://127.0.0.1:{web}/", None, default_incident(), log)
    try:
        assert wait_until(lambda: "serving incident" in log.read_text() or proc.poll() is not None, 60), log.read_text()
        assert proc.poll() is None, log.read_text()
        srv.client = client(f"tcp/127.0.0.1:{port}")
        try:
            yield srv
        finally:
            srv.client.close()
    finally:
        srv.stop()

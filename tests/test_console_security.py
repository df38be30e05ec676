"""The console knows who is at the keyboard (issue 19): logins per incident, HttpOnly +
SameSite=Strict session cookies, Host and Origin checked against the console's own address,
viewers read only, client-certificate login over HTTPS, revocation ends a session, and every
operator action reaches the recording with who did it. Against a real TLS router on loopback."""
from __future__ import annotations

import asyncio
import http.client
import json
import ssl
import time

import pytest

from client.console.server import ConsoleError, start_console
from service.protocol import pki, wire
from service.protocol.incident import default_incident
from service.review.recorder import IncidentRecorder, read_recording
from service.review.reprocess import reprocess
from tests.security_util import (
    DOOR,
    INCIDENT,
    PASSWORDS,
    identity,
    make_pki,
    matched_publisher,
    put_routed,
    secure_service,
    tls_client,
    walking_frames,
)
from tests.zenoh_util import wait_until


class Browser:
    """Requests as a browser on the console's page sends them: its Host and Origin, its cookie."""

    def __init__(self, port: int, https: bool = False, context: ssl.SSLContext | None = None,
                 host: str = "127.0.0.1"):
        self.port, self.https, self.context, self.host = port, https, context, host
        self.cookie: str | None = None
        self.origin = f"{'https' if https else 'http'}://{host}:{port}"

    def request(self, method: str, path: str, body=None, headers: dict | None = None):
        conn = (http.client.HTTPSConnection("127.0.0.1", self.port, context=self.context, timeout=10) if self.https
                else http.client.HTTPConnection("127.0.0.1", self.port, timeout=10))
        h = {"Host": f"{self.host}:{self.port}"}
        if method == "POST":
            h.update({"Origin": self.origin, "Content-Type": "application/json"})
        if self.cookie:
            h["Cookie"] = self.cookie
        h.update(headers or {})
        h = {k: v for k, v in h.items() if v is not None}
        conn.request(method, path, body=None if body is None else json.dumps(body), headers=h)
        res = conn.getresponse()
        raw = res.read()
        conn.close()
        data = json.loads(raw) if "json" in (res.getheader("Content-Type") or "") else raw
        return res.status, data, res.getheaders()

    def login(self, user: str, password: str):
        status, data, headers = self.request("POST", "/api/login", {"user": user, "password": password})
        cookies = [v for k, v in headers if k.lower() == "set-cookie"]
        if status == 200:
            self.cookie = cookies[0].split(";", 1)[0]
        return status, data, cookies


@pytest.fixture
def secured(tmp_path):
    """PKI, TLS router + service (recording), ff1 walking, console-1's console with logins."""
    d = make_pki(tmp_path / "pki")
    rec_path = tmp_path / "incident.mcap"
    recorder = IncidentRecorder(rec_path, INCIDENT).__enter__()
    with secure_service(d, recorder=recorder) as (svc, endpoint, tap):
        ff1 = tls_client(endpoint, identity(d, "ff1"))
        session = tls_client(endpoint, identity(d, "console-1"))
        console = start_console(session, default_incident(), port=0, actor="console-1", roster=d / "roster.json")
        try:
            frames = walking_frames("ff1", 12.0)
            head = [b for b in frames if b.t[-1] <= 1002.0]
            imu = matched_publisher(ff1, wire.key(INCIDENT, "ff1", "imu"))  # nothing put before the route is lost
            for b in head:
                imu.put(wire.encode(b))
            assert wait_until(lambda: svc.received["imu"] == len(head), 10)  # the door fix comes after these
            door = wire.Fix.checkpoint("ff1", float(head[-1].t[-1]), name=DOOR)  # a device names a surveyed checkpoint
            put_routed(ff1, wire.key(INCIDENT, "ff1", "fix"), wire.encode(door))  # ff1's own: placed at the door
            assert wait_until(lambda: svc.received["fix"] == 1, 10)
            for b in frames[len(head):]:
                imu.put(wire.encode(b))
            assert wait_until(lambda: console.board.device_time("ff1") is not None and svc.wait_idle(0.2), 20)
            yield d, svc, console, tap, rec_path
        finally:
            console.close()
            session.close()
            ff1.close()
    recorder.__exit__(None, None, None)


def test_no_login_no_data_and_no_action(secured):
    d, svc, console, tap, _ = secured
    b = Browser(console.port)
    assert b.request("GET", "/")[0] == 200  # the page itself (it shows the login form)
    status, info, _ = b.request("GET", "/api/session")
    assert status == 200 and info["auth"] == "required" and info["user"] is None
    for method, path in (("GET", "/api/incident"), ("GET", "/api/state"), ("GET", "/api/tracks"),
                         ("GET", "/plan/0.png")):
        assert b.request(method, path)[0] == 401, path
    status, body, _ = b.request("POST", "/api/fix", {"responder": "ff1", "x": 90.0, "y": 0.0, "floor": 0})
    assert status == 401 and "log in" in body["error"]
    for path, body in (("/api/checkpoint", {"name": "x", "x": 0.0, "y": 0.0, "floor": 0}),
                       ("/api/ack", {"responder": "ff1", "alarm": "man_down"}),
                       ("/api/command", {"action": "par"})):
        assert b.request("POST", path, body)[0] == 401
    assert svc.received["op"] == 0


def test_login_cookie_origin_host_roles_and_actions(secured):
    d, svc, console, tap, _ = secured
    b = Browser(console.port)
    assert b.login("alice", "wrong")[0] == 401
    assert b.login("nobody", "x")[0] == 401
    assert b.login("ff1", "x")[0] == 401  # a wearable's name is no login
    status, who, cookies = b.login("alice", PASSWORDS["alice"])
    assert status == 200 and (who["user"], who["role"], who["via"]) == ("alice", "operator", "password")
    attrs = [a.strip().lower() for a in cookies[0].split(";")]
    assert "httponly" in attrs and "samesite=strict" in attrs and "path=/" in attrs and "secure" not in attrs
    fix = {"responder": "ff1", "x": 2.0, "y": 3.0, "floor": 0}
    # a foreign Origin (another site's page in the officer's browser), a foreign Host (DNS rebinding), both
    for headers in ({"Origin": "http://evil.example"}, {"Host": "evil.example"},
                    {"Host": "evil.example", "Origin": "http://evil.example"}, {"Origin": "null"}):
        status, body, _ = b.request("POST", "/api/fix", fix, headers)
        assert status == 403, headers
    assert b.request("GET", "/api/state", headers={"Host": "evil.example:80"})[0] == 403
    assert svc.received["op"] == 0
    # the WebSocket: a foreign Origin is refused, the console's own page with a session is served
    assert asyncio.run(_ws(console.port, "http://evil.example", b.cookie)) == 403
    assert asyncio.run(_ws(console.port, b.origin, None)) == 401
    assert asyncio.run(_ws(console.port, b.origin, b.cookie)) == "snapshot"

    # every operator action, published as console-1's, naming alice
    status, body, _ = b.request("POST", "/api/fix", fix)
    assert status == 200 and body["operator"] == "alice" and body["key"] == wire.key(INCIDENT, "console-1", "op")
    assert b.request("POST", "/api/ack", {"responder": "ff1", "alarm": "man_down"})[0] == 200
    status, body, _ = b.request("POST", "/api/command", {"action": "par"})  # the roll call goes to ff1's wearable
    assert status == 200 and body["operator"] == "alice" and body["responders"] == ["ff1"]
    assert b.request("POST", "/api/checkpoint", {"name": "door-7", "x": 1.0, "y": 2.0, "floor": 0})[0] == 201
    assert wait_until(lambda: len(console.server.audits) == 4, 10), console.server.audits
    got = [(a["actor"], a["operator"], a["action"], a["outcome"]) for a in console.server.audits]
    assert got == [("console-1", "alice", "fix", "accepted"), ("console-1", "alice", "ack", "recorded"),
                   ("console-1", "alice", "par", "recorded"), ("console-1", "alice", "checkpoint", "recorded")]
    assert console.server.audits[2]["order"] == body["id"]

    # a viewer reads and does not act
    v = Browser(console.port)
    assert v.login("vic", PASSWORDS["vic"])[1]["role"] == "viewer"
    assert v.request("GET", "/api/state")[0] == 200
    status, body, _ = v.request("POST", "/api/fix", fix)
    assert status == 403 and "viewer" in body["error"]
    assert v.request("POST", "/api/ack", {"responder": "ff1", "alarm": "man_down"})[0] == 403
    assert v.request("POST", "/api/command", {"action": "evacuate"})[0] == 403

    # logout ends the session; revoking ends another's within a second or two
    assert v.request("POST", "/api/logout", {})[0] == 200
    assert v.request("GET", "/api/state")[0] == 401
    pki.revoke(d, "alice")
    assert wait_until(lambda: b.request("GET", "/api/state")[0] == 401, 5)
    assert b.login("alice", PASSWORDS["alice"])[0] == 401


def test_failed_logins_are_throttled(secured):
    _, _, console, _, _ = secured
    b = Browser(console.port)
    codes = [b.login("alice", f"guess-{i}")[0] for i in range(6)]
    assert codes == [401] * 5 + [429]


def test_every_operator_action_is_in_the_recording_with_who_did_it(secured):
    d, svc, console, tap, rec_path = secured
    b = Browser(console.port)
    b.login("alice", PASSWORDS["alice"])
    assert wait_until(lambda: svc.responders["ff1"].tracker.live is not None, 10)
    live = svc.responders["ff1"].tracker.live
    far = {"responder": "ff1", "x": live.x + 86.0, "y": live.y, "floor": 0}  # the forged-fix distance, by an operator
    assert b.request("POST", "/api/fix", far)[0] == 200
    assert wait_until(lambda: len(console.server.audits) == 1, 10)  # zenoh orders per key: one at a time
    status, par, _ = b.request("POST", "/api/command", {"action": "par"})
    assert status == 200
    assert b.request("POST", "/api/ack", {"responder": "ff1", "alarm": "man_down"})[0] == 200
    assert b.request("POST", "/api/checkpoint", {"name": "stair-B", "x": 4.0, "y": 1.0, "floor": 0})[0] == 201
    assert wait_until(lambda: len(console.server.audits) == 4 and svc.wait_idle(0.2), 10)
    flagged = console.server.audits[0]
    assert flagged["flags"] == ["implausible_jump"] and flagged["outcome"] == "accepted"
    assert console.server.flags["ff1"]["operator"] == "alice"  # shown on the console
    svc.recorder.flush_if_due(time.time() + 3600)
    svc.close()
    svc.recorder.__exit__(None, None, None)
    msgs = list(read_recording(rec_path))
    assert msgs[0].kind == "access"  # the policy the service enforced, before any input
    ops = [(m.responder, wire.decode(m.payload)) for m in msgs if m.kind == "op"]
    assert [(actor, op.operator, op.action) for actor, op in ops] == [
        ("console-1", "alice", "fix"), ("console-1", "alice", "par"), ("console-1", "alice", "ack"),
        ("console-1", "alice", "checkpoint")]
    assert (ops[2][1].alarm, ops[3][1].name, ops[1][1].order, ops[1][1].responders) == (
        "man_down", "stair-B", par["id"], ["ff1"])
    orders = [wire.decode(m.payload) for m in msgs if m.kind == "command"]
    assert [(c.responder, c.id, c.issued_by) for c in orders] == [("ff1", par["id"], "alice")]
    audits = [wire.decode(m.payload) for m in msgs if m.kind == "audit"]
    assert [(a.actor, a.operator, a.action, a.flags) for a in audits] == [
        ("console-1", "alice", "fix", ["implausible_jump"]), ("console-1", "alice", "par", []),
        ("console-1", "alice", "ack", []), ("console-1", "alice", "checkpoint", [])]
    # reprocessed, the recording gives the same verdicts
    again = reprocess(rec_path, default_incident())["audits"]
    assert [(a["actor"], a["operator"], a["action"], a["outcome"], a["flags"]) for a in again] == [
        (a.actor, a.operator, a.action, a.outcome, a.flags) for a in audits]


def test_client_certificate_login_over_https(tmp_path):
    d = make_pki(tmp_path / "pki")
    with secure_service(d) as (svc, endpoint, tap):
        session = tls_client(endpoint, identity(d, "console-1"))
        console = start_console(session, default_incident(), port=0, actor="console-1", roster=d / "roster.json",
                                tls=identity(d, "console-1"), https=True)
        try:
            assert console.url.startswith("https://127.0.0.1:")

            def context(name=None, pkidir=d):
                ctx = ssl.create_default_context(cafile=str(d / "ca.crt"))
                if name:
                    ctx.load_cert_chain(str(pkidir / name / "cert.pem"), str(pkidir / name / "key.pem"))
                return ctx
            b = Browser(console.port, https=True, context=context("alice"))
            status, info, _ = b.request("GET", "/api/session")
            assert info["certificate"] == "alice" and info["user"] is None
            status, who, headers = b.request("POST", "/api/login", {"certificate": True})
            assert status == 200 and (who["user"], who["via"]) == ("alice", "certificate")
            cookie = next(v for k, v in headers if k.lower() == "set-cookie")
            assert "secure" in [a.strip().lower() for a in cookie.split(";")]
            nocert = Browser(console.port, https=True, context=context())
            assert nocert.request("POST", "/api/login", {"certificate": True})[0] == 401
            assert nocert.login("vic", PASSWORDS["vic"])[0] == 200  # the password works on HTTPS too
            wearable = Browser(console.port, https=True, context=context("ff1"))  # a device is no operator
            assert wearable.request("POST", "/api/login", {"certificate": True})[0] == 401
            other = make_pki(tmp_path / "other")  # a certificate of another CA: the handshake fails
            with pytest.raises((ssl.SSLError, ConnectionError, OSError)):
                Browser(console.port, https=True, context=context("alice", other)).request("GET", "/api/session")
        finally:
            console.close()
            session.close()


def test_unsafe_console_setups_are_refused(tmp_path):
    d = make_pki(tmp_path / "pki")
    with secure_service(d) as (svc, endpoint, tap):
        session = tls_client(endpoint, identity(d, "console-1"))
        try:
            cfg = default_incident()
            with pytest.raises(ConsoleError, match="needs logins"):
                start_console(session, cfg, port=0, host="10.255.255.1", tls=identity(d, "console-1"))
            with pytest.raises(ConsoleError, match="HTTPS"):
                start_console(session, cfg, port=0, host="10.255.255.1", roster=d / "roster.json")
            with pytest.raises(ConsoleError, match="--origin"):
                start_console(session, cfg, port=0, host="0.0.0.0", roster=d / "roster.json",
                              tls=identity(d, "console-1"))
        finally:
            session.close()


async def _ws(port: int, origin: str, cookie: str | None):
    import aiohttp

    headers = {"Origin": origin, **({"Cookie": cookie} if cookie else {})}
    async with aiohttp.ClientSession() as s:
        try:
            async with s.ws_connect(f"http://127.0.0.1:{port}/ws", headers=headers) as ws:
                msg = await ws.receive(timeout=10)
                return json.loads(msg.data)["type"]
        except aiohttp.WSServerHandshakeError as e:
            return e.status

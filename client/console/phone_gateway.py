"""The phone gateway: a phone's browser page (``/wear``) publishes as a wearable through the console.

A phone cannot speak zenoh; it speaks a WebSocket to the console (``/wear/ws``), and the
gateway publishes what it sends as the responder its token names, through the same
:class:`client.wearable.Wearable` a replay uses: the same schema and codec, the same keys
(``firetrack/{incident}/{responder}/imu``, ``.../fix``, ``.../ack``, presence), the same
keep and resend when the service's ``Status.missing`` asks, the same acknowledgement. One
``Wearable`` per phone stream (responder, ``boot``: one start of the page), kept across the
phone's reconnects for :data:`LINK_GRACE_S`, so a phone that lost its network for a while
resumes the same stream.

Messages (JSON text frames; the page is ``static/wear/``):

========================  ======================================================================
phone -> gateway
``hello``                 ``{token, device, boot}``: first message; the answer is ``welcome``
                          with ``published`` (the newest seq the gateway has put of this stream)
                          and ``acked`` (the newest the service took): the page resends the rest
``frame``                 ``{seq, t, acc, gyr, [mag], carry, utc_offset, [responder]}``: one
                          :class:`service.protocol.wire.ImuBatch` (device clock s, m/s², rad/s, µT)
``fix``                   ``{t, lat, lon, accuracy}``: a GNSS fix on the device clock
``ack``                   ``{id}``: the wearer acknowledged the order ``id``
``ok``                    ``{t}``: the wearer answered the man-down prompt "I'm OK" at device time
                          ``t`` (an :class:`service.protocol.wire.Ack` with action ``ok``)
gateway -> phone
``acked``                 ``{seq, lost}``: the service's acknowledgement of this stream
``state``                 once a second: ``heard`` (a service subscribes), ``sigma_m`` (the
                          position's 1-sigma radius the service publishes), ``alarms``, ``steps``,
                          ``t`` (the newest device time the service took), ``man_down_at`` (set:
                          the page asks "Are you OK?", counting down to it) and ``ok_at``
``command``               an order (``par``, ``evacuate``) for the wearer to acknowledge
``refused``               ``{reason, detail}``: a message not taken (counted against the token)
========================  ======================================================================

A frame that names another responder than the token's is refused and counted
(``another_responder``); a revoked token is refused from its next message and its socket is
closed (:class:`client.console.enrolment.PhoneEnrolments`).
"""
from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
from aiohttp import WSMsgType, web

from client.console.enrolment import CODE_TTL_S, PhoneEnrolments
from client.console.requests import POST_MAX_BYTES, HttpError, error_response, read_json, responder_id
from client.wearable import Wearable
from service.protocol import wire

log = logging.getLogger("firetrack.console")

LINK_GRACE_S = 60.0  # s a phone stream outlives its socket (a phone out of coverage comes back to it)
ACK_POLL_S = 0.1  # s between looks at the service's acknowledgement
STATE_EVERY_S = 1.0  # s between state messages to the phone
PAGE_CARRY = {"hand": "handheld", "pocket": "pocket", "chest": "chest", "boot": "foot"}  # page choice -> ImuBatch.carry


class Refused(ValueError):
    """A phone message not taken: ``reason`` (a counter name) and what was wrong."""

    def __init__(self, reason: str, detail: str):
        super().__init__(detail)
        self.reason = reason


@dataclass
class PhoneStream:
    """One start of a phone's page (responder, boot), published through a :class:`Wearable`."""

    token: str
    responder: str
    device: str
    boot: str
    wearable: Wearable
    published: int | None = None  # newest seq put on the network
    sockets: set = field(default_factory=set)
    left_at: float | None = None  # when its last socket closed
    commands: dict = field(default_factory=dict)  # order id -> wire.Command, until acknowledged
    acks: int = 0


def _vectors(body: dict, name: str, n: int, required: bool = True) -> np.ndarray | None:
    v = body.get(name)
    if v is None and not required:
        return None
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise Refused("schema", f"{name}: not an array of numbers") from None
    if a.shape != (n, 3):
        raise Refused("shape", f"{name}: {a.shape} for {n} samples (want {n} rows of x, y, z)")
    return a


def frame_batch(body: dict, stream: PhoneStream) -> wire.ImuBatch:
    """The :class:`ImuBatch` of a ``frame`` message, validated by the wire schema (the same
    checks the service makes), or :class:`Refused`."""
    named = body.get("responder")
    if named is not None and named != stream.responder:
        raise Refused("another_responder", f"this phone is enrolled as {stream.responder!r}, not {str(named)[:64]!r}")
    try:
        t = np.asarray(body.get("t"), dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise Refused("schema", "t: not an array of numbers") from None
    n = t.shape[0]
    carry = PAGE_CARRY.get(body.get("carry"), "unknown")
    offset = body.get("utc_offset")
    try:
        return wire.ImuBatch(responder=stream.responder, device=stream.device, boot=stream.boot, seq=body.get("seq"),
                             t=t, acc=_vectors(body, "acc", n), gyr=_vectors(body, "gyr", n),
                             mag=_vectors(body, "mag", n, required=False), carry=carry,
                             utc_offset=offset if isinstance(offset, (int, float)) and math.isfinite(offset) else None)
    except ValueError as e:  # pydantic's ValidationError: the schema's sentence names the field
        raise Refused("schema", " ".join(str(e).split())[:300]) from None


def fix_message(body: dict, stream: PhoneStream) -> wire.Fix:
    try:
        return wire.Fix.gnss(stream.responder, body.get("t"), lat=body.get("lat"), lon=body.get("lon"),
                             accuracy=body.get("accuracy"), operator="phone")
    except ValueError as e:
        raise Refused("fix", " ".join(str(e).split())[:300]) from None


def qr_svg(text: str) -> str:
    """An SVG QR code of ``text`` (segno, a pure-Python encoder: the console's extra)."""
    import segno
    return segno.make(text, error="m", micro=False).svg_inline(scale=6, border=4, dark="#000", light="#fff")


def sigma_m(pose: dict | None) -> float | None:
    """m: the 1-sigma radius of a pose's position in its worst direction (largest eigenvalue of cov)."""
    if pose is None:
        return None
    xx, xy, yy = pose["cov"]
    m, d = (xx + yy) / 2, math.hypot((xx - yy) / 2, xy)
    return math.sqrt(max(m + d, 0.0))


class PhoneGateway:
    """The phones' routes of one console; composed into :class:`client.console.server.ConsoleServer`."""

    def __init__(self, session, incident: str, board, enrolments: PhoneEnrolments | None = None, logins=None):
        self.session, self.incident, self.board = session, incident, board
        self.logins = logins  # the console's limiter of failed logins: wrong codes count as failures too
        self.enrolments = enrolments or PhoneEnrolments(incident)
        self.enrolments.on_revoked = self._revoked
        self.streams: dict[tuple[str, str], PhoneStream] = {}
        self.counts = {"frames": 0, "fixes": 0, "acks": 0, "oks": 0, "resent_by_phone": 0, "duplicates": 0,
                       "refused": 0}
        self._loop: asyncio.AbstractEventLoop | None = None

    def publish_through(self, session) -> None:
        """Publish the phones' streams through ``session`` (a client of the router under a
        gateway identity, which the router's access control limits to the roster's
        wearables: ``firetrack console --gateway-tls``), not the console's own."""
        self.session = session

    def add_routes(self, router: web.UrlDispatcher, static_dir, operator, base_url) -> None:
        """The phone's routes, and the operators' (``operator(request)``: the acting session or
        :class:`HttpError` 403; ``base_url()``: the address phones open, for the QR code)."""
        self._static, self._operator, self._base_url = static_dir, operator, base_url
        router.add_get("/wear", self._page)
        router.add_get("/wear/ws", self._socket)
        router.add_post("/wear/claim", self._claim)
        router.add_get("/api/phones", self._phones)
        router.add_post("/api/phones", self._enrol)
        router.add_post("/api/phones/revoke", self._revoke)

    PUBLIC = ("/wear", "/wear/ws", "/wear/claim")  # the phone has a token, not a login

    async def _page(self, request: web.Request) -> web.FileResponse:
        return web.FileResponse(self._static / "wear.html", headers={"Cache-Control": "no-cache"})

    async def _phones(self, request: web.Request) -> web.Response:
        return web.json_response(self.stats())

    async def _enrol(self, request: web.Request) -> web.Response:
        """An operator enrols a phone for a responder: its short code, and a QR code of the
        page's address with the code (an SVG the console shows)."""
        try:
            who = self._operator(request)
            rid = responder_id(await read_json(request))
        except HttpError as e:
            return error_response(e.status, e.args[0])
        g = self.enrolments.enrol(rid, issued_by=who.user)
        url = f"{self._base_url().rstrip('/')}/wear#code={g.code}"
        return web.json_response({"responder": rid, "code": g.code, "url": url, "expires_in_s": CODE_TTL_S,
                                  "qr_svg": qr_svg(url)}, status=201)

    async def _revoke(self, request: web.Request) -> web.Response:
        try:
            self._operator(request)
            rid = responder_id(await read_json(request))
        except HttpError as e:
            return error_response(e.status, e.args[0])
        return web.json_response({"responder": rid, "revoked": self.enrolments.revoke(rid)})

    async def _claim(self, request: web.Request) -> web.Response:
        """A phone trades a short code for its token; wrong codes from an address are counted
        with the console's failed logins (429 after a few in a minute: no guessing codes)."""
        address = request.remote or "?"
        if self.logins is not None and self.logins.throttled(address):
            return error_response(429, "too many wrong codes from this address: wait a minute")
        try:
            body = await read_json(request)
        except HttpError as e:
            return error_response(e.status, e.args[0])
        g = self.enrolments.claim(str(body.get("code", ""))[:32])
        if g is None:
            if self.logins is not None:
                self.logins.count_failure(address, "a phone enrolment code")
            return error_response(404, "this code is unknown, expired or used: ask the console for a new one")
        return web.json_response({"token": g.token, "responder": g.responder, "incident": g.incident})

    # ------------------------------------------------------------------ the phone's socket
    async def _socket(self, request: web.Request) -> web.StreamResponse:
        self._loop = asyncio.get_running_loop()
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=POST_MAX_BYTES)
        await ws.prepare(request)
        stream: PhoneStream | None = None
        watcher = None
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    if msg.type == WSMsgType.ERROR:
                        break
                    continue
                try:
                    body = json.loads(msg.data)
                    if not isinstance(body, dict):
                        raise Refused("schema", "a message is a JSON object")
                except (ValueError, RecursionError) as e:
                    await self._refuse(ws, None, Refused("schema", f"not JSON: {str(e)[:100]}"))
                    continue
                if stream is None:
                    stream = await self._hello(ws, body)
                    if stream is None:
                        break
                    watcher = asyncio.get_running_loop().create_task(self._watch(ws, stream))
                    continue
                if self.enrolments.grant(stream.token) is None:
                    self.enrolments.refuse(stream.token, "revoked")
                    self.counts["refused"] += 1
                    await ws.close(code=4401, message=b"token revoked")
                    break
                try:
                    self._take(stream, body)
                except Refused as e:
                    await self._refuse(ws, stream, e)
        finally:
            if watcher is not None:
                watcher.cancel()
            if stream is not None:
                stream.sockets.discard(ws)
                if not stream.sockets:
                    stream.left_at = time.monotonic()
                    asyncio.get_running_loop().call_later(LINK_GRACE_S + 0.1, self._expire, stream)
        return ws

    async def _refuse(self, ws, stream: PhoneStream | None, e: Refused) -> None:
        self.counts["refused"] += 1
        if stream is not None:
            self.enrolments.refuse(stream.token, e.reason)
        log.info("phone gateway: refused %s: %s", e.reason, e)
        await ws.send_json({"type": "refused", "reason": e.reason, "detail": str(e)})

    async def _hello(self, ws, body: dict) -> PhoneStream | None:
        token = body.get("token")
        grant = self.enrolments.grant(token) if body.get("type") == "hello" else None
        if grant is None:
            if isinstance(token, str):
                self.enrolments.refuse(token, "revoked_or_unknown")
            self.counts["refused"] += 1
            await ws.send_json({"type": "refused", "reason": "token",
                                "detail": "say hello with a token of this incident's console (enrol the phone again)"})
            await ws.close(code=4401, message=b"no valid token")
            return None
        device, boot = str(body.get("device") or "phone")[:128], str(body.get("boot") or "")[:64]
        if not boot:
            boot = f"page-{int(time.time())}"
        key = (grant.responder, boot)
        stream = self.streams.get(key)
        if stream is None or stream.token != token:
            if stream is not None:  # the same boot under another token: a new stream of its own
                self._close_stream(stream)
            w = Wearable(self.session, self.incident, grant.responder, boot=boot, auto_ack=False,
                         on_command=lambda cmd, k=key: self._command_from_zenoh(k, cmd))
            stream = PhoneStream(token=token, responder=grant.responder, device=device, boot=boot, wearable=w)
            self.streams[key] = stream
        stream.sockets.add(ws)
        stream.left_at = None
        await ws.send_json({"type": "welcome", "responder": grant.responder, "incident": self.incident,
                            "published": stream.published, "acked": stream.wearable.acked_seq,
                            "commands": [self._command_json(c) for c in stream.commands.values()]})
        return stream

    def _take(self, stream: PhoneStream, body: dict) -> None:
        kind = body.get("type")
        if kind == "frame":
            batch = frame_batch(body, stream)
            if stream.published is not None and batch.seq <= stream.published:
                self.counts["duplicates"] += 1  # already put (a resend after a reconnect): the keep has it
                return
            stream.wearable.send("imu", batch)
            stream.published = batch.seq
            self.counts["frames"] += 1
            if body.get("resent"):
                self.counts["resent_by_phone"] += 1
        elif kind == "fix":
            stream.wearable.send("fix", fix_message(body, stream))
            self.counts["fixes"] += 1
        elif kind == "ack":
            cmd = stream.commands.pop(str(body.get("id")), None)
            if cmd is None:
                raise Refused("ack", f"no open order {str(body.get('id'))[:64]!r} for {stream.responder}")
            stream.wearable.acknowledge(cmd)
            stream.acks += 1
            self.counts["acks"] += 1
        elif kind == "ok":
            t = body.get("t")
            if not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t):
                raise Refused("ok", f"t: the device time of the answer, a number (got {str(t)[:32]!r})")
            stream.wearable.answer_prompt(float(t))
            self.counts["oks"] += 1
        else:
            raise Refused("kind", f"unknown message type {str(kind)[:32]!r} (frame, fix, ack, ok)")

    async def _watch(self, ws, stream: PhoneStream) -> None:
        """Tell the phone what the service acknowledged, as it changes, and its state each second."""
        acked, last_state = None, 0.0
        try:
            while not ws.closed:
                w = stream.wearable
                if w.acked_seq != acked:
                    acked = w.acked_seq
                    await ws.send_json({"type": "acked", "seq": acked, "lost": w.service_lost})
                now = time.monotonic()
                if now - last_state >= STATE_EVERY_S:
                    last_state = now
                    pose, status = self.board.latest(stream.responder)
                    status = status or {}
                    await ws.send_json({"type": "state", "heard": w.heard, "sigma_m": sigma_m(pose),
                                        "alarms": status.get("alarms", []), "steps": pose["steps"] if pose else 0,
                                        "floor": pose["floor"] if pose else None, "t": status.get("t"),
                                        "man_down_at": status.get("man_down_at"), "ok_at": status.get("ok_at")})
                await asyncio.sleep(ACK_POLL_S)
        except (ConnectionError, RuntimeError):
            pass

    # ------------------------------------------------------------------ orders, from zenoh's thread
    @staticmethod
    def _command_json(cmd: wire.Command) -> dict:
        return {"type": "command", "id": cmd.id, "action": cmd.action, "issued_at": cmd.issued_at,
                "issued_by": cmd.issued_by}

    def _command_from_zenoh(self, key, cmd: wire.Command) -> None:
        loop = self._loop
        if loop is not None and loop.is_running():
            loop.call_soon_threadsafe(self._command, key, cmd)

    def _command(self, key, cmd: wire.Command) -> None:
        stream = self.streams.get(key)
        if stream is None:
            return
        stream.commands[cmd.id] = cmd
        text = json.dumps(self._command_json(cmd))
        for ws in list(stream.sockets):
            asyncio.get_running_loop().create_task(ws.send_str(text))

    # ------------------------------------------------------------------ ends
    def _expire(self, stream: PhoneStream) -> None:
        if stream.sockets or stream.left_at is None or time.monotonic() - stream.left_at < LINK_GRACE_S:
            return
        self._close_stream(stream)

    def _close_stream(self, stream: PhoneStream) -> None:
        if self.streams.get((stream.responder, stream.boot)) is stream:
            del self.streams[(stream.responder, stream.boot)]
        stream.wearable.close()

    def _revoked(self, tokens: list[str]) -> None:
        """Tokens revoked (by the console's loop or a test's thread): their sockets close now,
        their streams withdraw their presence."""
        loop = self._loop
        if loop is None or not loop.is_running():
            return
        loop.call_soon_threadsafe(self._end_tokens, set(tokens))

    def _end_tokens(self, tokens: set[str]) -> None:
        for stream in [s for s in self.streams.values() if s.token in tokens]:
            for ws in list(stream.sockets):
                asyncio.get_running_loop().create_task(ws.close(code=4401, message=b"token revoked"))
            self._close_stream(stream)

    def close(self) -> None:
        for stream in list(self.streams.values()):
            self._close_stream(stream)

    def stats(self) -> dict:
        return {**self.counts, "streams": len(self.streams), "refused_by_reason": dict(self.enrolments.refused_total()),
                "phones": self.enrolments.listing()}

"""The console's web server: the page, the incident, live updates over a WebSocket, operator actions.

``start_console(session, cfg, port)`` runs an aiohttp server on its own asyncio loop in a
background thread and subscribes the given zenoh session to ``firetrack/{incident}/*/pose``
and ``.../status``. ``handle.close()`` undeclares the subscribers, closes the pages'
WebSockets and stops the server and its thread, each step bounded in time.

HTTP API (JSON; errors are ``{"error": "..."}`` with a 4xx status naming what is wrong):

======================  =========================================================================
``GET /``               the page (``static/index.html``); ``/static/*`` its modules, style, Leaflet
``GET /ws``             WebSocket: a ``snapshot`` on connect, then one ``update`` per batch period
                        (latest pose/status of each changed responder), ``checkpoints`` and ``fix``
``GET /api/incident``   floors, checkpoints, a plan per floor (image URL, size, pixel -> ENU matrix)
``GET /plan/{n}.png``   the plan image of floor ``n``, downscaled once (:mod:`client.console.plans`)
``GET /api/track/{id}`` a responder's smoothed track from the service's ``.../track`` queryable
``GET /api/tracks``     every responder's track (one wildcard query), for the review slider
``GET /api/state``      what the console holds now (poses, statuses, trails, reject counts)
``GET /api/session``    who is logged in here (``user``, ``role``) and whether a login is needed
``POST /api/login``     ``{user, password}`` or ``{certificate: true}`` (HTTPS with a client
                        certificate): a session cookie; 401 when wrong, 429 after repeated failures
``POST /api/logout``    ends the session
``POST /api/fix``       ``{responder, x, y, floor}`` or ``{responder, name}`` [``sigma``]: a checkpoint
                        :class:`service.protocol.wire.Fix` stamped with the responder's latest device
                        time, published as an operator action (``.../{actor}/op``) naming the operator
``POST /api/checkpoint``  ``{name, x, y, floor}`` [``sigma_m``, ``note``]: add a named checkpoint
``POST /api/ack``       ``{responder, alarm}``: an alarm acknowledged (recorded by the service)
``/wear``, ``/api/phones``  phones as wearables (:mod:`client.console.phone_gateway`)
======================  =========================================================================

The routes are grouped by what they serve: this module keeps the lifecycle, the page, the
live feed and the guard; :mod:`client.console.login_routes` the logins,
:mod:`client.console.actions` the operator actions, :mod:`client.console.track_routes` the
tracks, and :mod:`client.console.requests` what a request body must be.

Security (:mod:`client.console.auth`): every request's ``Host`` must be one of the console's
own addresses and a POST's or WebSocket's ``Origin`` one of its origins (403 otherwise); with
a roster every API call and the live feed need a login (401), and only operators act
(viewers get 403). POST bodies must be ``application/json`` too. Operator actions go to the
service as :class:`service.protocol.wire.OperatorAction` on ``firetrack/{incident}/{actor}/op``
(``actor``: this console's certificate name), which the service records and answers with an
:class:`service.protocol.wire.Audit` (shown as a notice, and as a flag on the responder when
the fix was an implausible jump).
"""
from __future__ import annotations

import asyncio
import errno
import json
import logging
import mimetypes
import threading
import time
from pathlib import Path

import zenoh
from aiohttp import WSMsgType, web

from client.console.actions import OperatorActions, checkpoints_json
from client.console.auth import (
    SESSION_COOKIE,
    Logins,
    SiteError,
    SitePolicy,
    is_loopback,
    server_ssl_context,
)
from client.console.live import LiveBoard
from client.console.login_routes import LoginRoutes
from client.console.phone_gateway import PhoneGateway
from client.console.plans import grid_matrix, plan_png, plan_problem, served_plan
from client.console.requests import POST_MAX_BYTES, SESSION_KEY, actor_session, error_response
from client.console.track_routes import TrackRoutes
from service.protocol import wire
from service.protocol.incident import IncidentConfig

log = logging.getLogger("firetrack.console")

# The page is ES modules, which browsers run only when served with a JavaScript type. aiohttp
# >= 3.10 types static files from Python's own table; older ones from the system's, where .js
# can be text/plain (the Windows registry): say what .js and .css are.
mimetypes.add_type("text/javascript", ".js")
mimetypes.add_type("text/css", ".css")
mimetypes.add_type("application/manifest+json", ".webmanifest")

STATIC_DIR = Path(__file__).resolve().parent / "static"
BATCH_PERIOD_S = 0.15  # one update message per page at most this often
LOST_CONTACT_S = 10.0  # the page raises lost_contact when nothing is heard of a responder for this long
CLIENT_BACKLOG = 20  # messages queued for a slow page before they are replaced by one snapshot
START_TIMEOUT_S = 10.0
STOP_TIMEOUT_S = 5.0
AUDITS_KEPT = 200  # recent audits (operator actions, flags) a page gets in its snapshot
PUBLIC_PATHS = ("/", "/api/session", "/api/login", "/api/logout")  # besides /static/: what a logged-out page may load


class ConsoleError(RuntimeError):
    """The console cannot start (the port is taken, the address is not this machine's, ...)."""


class _Page:
    """One connected page: a queue its own task drains, so a slow page never holds up the others."""

    def __init__(self, ws: web.WebSocketResponse):
        self.ws = ws
        self.queue: asyncio.Queue[str] = asyncio.Queue()
        self.behind = False  # set when the backlog overflowed: the next message is a fresh snapshot

    def push(self, text: str) -> None:
        if self.queue.qsize() >= CLIENT_BACKLOG:
            while not self.queue.empty():
                self.queue.get_nowait()
            self.behind = True
        self.queue.put_nowait(text)

    async def run(self, snapshot) -> None:
        try:
            while not self.ws.closed:
                text = await self.queue.get()
                if self.behind:
                    self.behind = False
                    text = snapshot()
                await self.ws.send_str(text)
        except (ConnectionError, RuntimeError) as e:  # the page went away mid-send: its handler cleans up
            log.info("console: a page stopped listening: %s", e)


class ConsoleServer:
    """The aiohttp application and its loop thread; use :func:`start_console`. The routes of
    logins, operator actions and tracks are collaborators it holds (``login_routes``,
    ``actions``, ``tracks``), each given what it uses."""

    def __init__(self, session: zenoh.Session, cfg: IncidentConfig, host: str, port: int,
                 batch_period_s: float = BATCH_PERIOD_S, lost_contact_s: float = LOST_CONTACT_S,
                 static_dir: Path = STATIC_DIR, actor: str = "console", logins: Logins | None = None,
                 tls=None, https: bool = False, origins: list[str] | None = None):
        self.session = session
        self.actor = actor
        self.logins = logins or Logins(None)
        self.tls, self.https, self.origins = tls, https, origins
        self.site: SitePolicy | None = None
        self.audits: list[dict] = []
        self.flags: dict[str, dict] = {}  # responder -> its latest flagged fix (audit)
        self.cfg, self.host, self.port = cfg, host, port
        self.batch_period_s, self.lost_contact_s = batch_period_s, lost_contact_s
        self.static_dir = Path(static_dir)
        self.board = LiveBoard()
        self.pages: set[_Page] = set()
        self.login_routes = LoginRoutes(self.logins, cfg.id, https)
        self.actions = OperatorActions(session, cfg, actor, self.board, self._send_all)
        self.tracks = TrackRoutes(session, cfg.id)
        self.phones = PhoneGateway(session, cfg.id, self.board, logins=self.logins)  # /wear: phones as wearables
        self._subs: list = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None
        self._broadcaster: asyncio.Task | None = None
        self._closed = False

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> ConsoleServer:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run_loop, name="firetrack-console", daemon=True)
        self._thread.start()
        try:
            asyncio.run_coroutine_threadsafe(self._serve(), self._loop).result(START_TIMEOUT_S)
        except OSError as e:
            self._stop_loop()
            why = {errno.EADDRINUSE: "the port is in use by another program (choose another with --port)",
                   errno.EACCES: "permission denied (ports below 1024 need privileges)",
                   errno.EADDRNOTAVAIL: f"{self.host} is not an address of this machine"}.get(e.errno, str(e))
            raise ConsoleError(f"cannot serve the console on {self._scheme}://{self.host}:{self.port}/: {why}") from None
        except SiteError as e:
            self._stop_loop()
            raise ConsoleError(str(e)) from None
        except BaseException:
            self._stop_loop()
            raise
        iid = self.cfg.id
        self.logins.on_revoked = self._revoked_from_thread
        try:
            for kind in ("pose", "status"):
                self._subs.append(self.session.declare_subscriber(
                    wire.key_all(iid, kind),
                    lambda s, kind=kind: self.board.on_sample(kind, str(s.key_expr), s.payload.to_bytes())))
            self._subs.append(self.session.declare_subscriber(
                wire.key_all(iid, "audit"), lambda s: self._on_audit(s.payload.to_bytes())))
        except Exception as e:  # a closed session: stop the server again, say why
            self.close()
            raise ConsoleError(f"cannot subscribe to the poses of incident {iid!r}: {e}") from None
        log.info("console for incident %r on %s", iid, self.url)
        return self

    @property
    def _scheme(self) -> str:
        return "https" if self.https else "http"

    @property
    def url(self) -> str:
        if self.site is not None:
            return self.site.primary + "/"
        return f"{self._scheme}://{self.host}:{self.port}/"

    def _run_loop(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_forever()
        finally:
            self._loop.close()

    def _stop_loop(self) -> None:
        if self._loop is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
        if self._thread is not None:
            self._thread.join(STOP_TIMEOUT_S)

    async def _serve(self) -> None:
        app = web.Application(client_max_size=POST_MAX_BYTES, middlewares=[self._guard])
        r = app.router
        r.add_get("/", self._index)
        r.add_static("/static/", self.static_dir, show_index=False)
        r.add_get("/ws", self._websocket)
        r.add_get("/api/incident", self._incident)
        r.add_get("/api/state", self._state)
        r.add_get(r"/plan/{floor:-?\d+}.png", self._plan)
        for routes in (self.tracks, self.login_routes, self.actions):
            routes.add_routes(r)
        self.phones.add_routes(r, self.static_dir, actor_session, lambda: self.url)
        runner = web.AppRunner(app, access_log=None, shutdown_timeout=1.0)
        await runner.setup()
        ssl_ctx = server_ssl_context(self.tls, request_client_cert=not self.logins.open) if self.https else None
        site = web.TCPSite(runner, self.host, self.port, ssl_context=ssl_ctx)
        try:
            await site.start()
        except BaseException:
            await runner.cleanup()
            raise
        self._runner = runner
        self.port = int(runner.addresses[0][1])  # the real one when port 0 asked for any free port
        try:
            self.site = SitePolicy.for_server(self.host, self.port, self.https, self.origins)
        except SiteError:
            await runner.cleanup()
            raise
        self._broadcaster = asyncio.get_running_loop().create_task(self._broadcast())

    def close(self) -> None:
        """Undeclare the subscribers, close every page's WebSocket, stop the server (bounded)."""
        if self._closed:
            return
        self._closed = True
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # the session is closed already: the subscriber went with it
                pass
        self._subs.clear()
        if self._loop is not None and self._loop.is_running():
            try:
                asyncio.run_coroutine_threadsafe(self._shutdown(), self._loop).result(STOP_TIMEOUT_S)
            except Exception as e:  # shutting down: say so, go on stopping the loop
                log.warning("console shutdown: %s", e)
        self._stop_loop()
        self.phones.close()
        self.logins.close()

    async def _shutdown(self) -> None:
        if self._broadcaster is not None:
            self._broadcaster.cancel()
        for page in list(self.pages):
            try:
                await asyncio.wait_for(page.ws.close(code=1001, message=b"console shutting down"), 1.0)
            except Exception:
                pass
        if self._runner is not None:
            await self._runner.cleanup()
        # whatever is left (a request waiting on a track query or a plan image): cancel, wait briefly
        rest = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for t in rest:
            t.cancel()
        if rest:
            await asyncio.wait(rest, timeout=1.0)

    # ------------------------------------------------------------------ live updates
    def _snapshot_text(self) -> str:
        return json.dumps({"type": "snapshot", "now": time.time(), **self.board.snapshot(),
                           "flags": self.flags, "audits": self.audits[-20:]})

    def _on_audit(self, payload: bytes) -> None:
        """The service's verdict on an action (or a flagged checkpoint fix): to every page,
        from zenoh's thread to the console's loop."""
        try:
            a = wire.decode(payload, expect=wire.Audit)
        except wire.WireError as e:
            log.warning("console: an audit message not understood: %s", e)
            return
        d = {k: v for k, v in a.model_dump().items() if v is not None}
        if self._loop is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._take_audit, d)

    def _take_audit(self, d: dict) -> None:
        self.audits.append(d)
        del self.audits[:-AUDITS_KEPT]
        if "implausible_jump" in d.get("flags", []) and d.get("responder"):
            self.flags[d["responder"]] = d
        self._send_all({"type": "audit", "now": time.time(), "audit": d})

    def _send_all(self, message: dict) -> None:
        text = json.dumps(message)
        for page in list(self.pages):
            page.push(text)

    async def _broadcast(self) -> None:
        while True:
            await asyncio.sleep(self.batch_period_s)
            if not self.pages:
                continue
            changes = self.board.take_changes()
            if changes is not None:
                self._send_all({"type": "update", "now": time.time(), **changes})

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        # browsers let any site open a WebSocket to this machine: the guard checked Host, Origin and the session
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=POST_MAX_BYTES)
        await ws.prepare(request)
        request[SESSION_KEY].sockets.add(ws)
        page = _Page(ws)
        page.push(self._snapshot_text())
        self.pages.add(page)
        sender = asyncio.get_running_loop().create_task(page.run(self._snapshot_text))
        try:
            async for msg in ws:  # the page only listens; its actions are HTTP requests
                if msg.type == WSMsgType.ERROR:
                    break
        finally:
            self.pages.discard(page)
            request[SESSION_KEY].sockets.discard(ws)
            sender.cancel()
        return ws

    def _revoked_from_thread(self, sessions) -> None:
        loop = self._loop
        if loop is not None and loop.is_running() and not self._closed:
            loop.call_soon_threadsafe(self._close_sockets, sessions)

    def _close_sockets(self, sessions) -> None:
        """Sessions ended by a revocation: their live feeds close at once."""
        for s in sessions:
            for ws in list(s.sockets):
                asyncio.get_running_loop().create_task(ws.close(code=4401, message=b"session ended: revoked"))

    # ------------------------------------------------------------------ the guard: Host, Origin, session
    @web.middleware
    async def _guard(self, request: web.Request, handler):
        site = self.site
        if site is None:
            return error_response(503, "the console is starting")
        problem = site.host_problem(request.headers.get("Host"))
        if problem is None and (request.method not in ("GET", "HEAD", "OPTIONS") or request.path == "/ws"):
            problem = site.origin_problem(request.headers.get("Origin"))
        if problem is not None:
            log.warning("console: refused %s %s: %s", request.method, request.path, problem)
            return error_response(403, problem)
        session = self.logins.session(request.cookies.get(SESSION_COOKIE))
        request[SESSION_KEY] = session
        if (session is None and request.path not in PUBLIC_PATHS + PhoneGateway.PUBLIC
                and not request.path.startswith("/static/")):
            return error_response(401, "log in first (POST /api/login)")
        return await handler(request)

    # ------------------------------------------------------------------ pages and data
    async def _index(self, request: web.Request) -> web.FileResponse:
        return web.FileResponse(self.static_dir / "index.html", headers={"Cache-Control": "no-cache"})

    def incident_json(self) -> dict:
        cfg = self.cfg
        plans = {}
        for f in cfg.floors:
            sp = served_plan(cfg, f.number)
            plans[str(f.number)] = sp.to_json() if sp is not None else {
                "floor": f.number, "url": None, "matrix": grid_matrix(), "problem": plan_problem(cfg, f.number)}
        return {
            "id": cfg.id, "name": cfg.name, "origin": cfg.origin.model_dump(), "start_floor": cfg.start_floor,
            "floors": [{"number": f.number, "name": f.name, "elevation_m": f.elevation_m} for f in cfg.floors],
            "checkpoints": checkpoints_json(cfg), "plans": plans,
            "beacons": [{"id": b.id, "name": b.name, "x": b.x, "y": b.y, "floor": b.floor, "sigma_m": b.sigma_m}
                        for b in cfg.beacons],
            "roster": [m.model_dump() for m in cfg.roster],
            "settings": {"lost_contact_s": self.lost_contact_s, "batch_period_s": self.batch_period_s,
                         "trail_points": self.board.trail_points},
        }

    async def _incident(self, request: web.Request) -> web.Response:
        return web.json_response(self.incident_json())

    async def _state(self, request: web.Request) -> web.Response:
        snap = self.board.snapshot()
        snap.update(pages=len(self.pages), fixes_sent=self.actions.fixes_sent, received=dict(self.board.received),
                    flags=self.flags, audits=self.audits[-20:])
        return web.json_response(snap)

    async def _plan(self, request: web.Request) -> web.Response:
        floor = int(request.match_info["floor"])
        numbers = [f.number for f in self.cfg.floors]
        if floor not in numbers:
            return error_response(404, f"floor {floor} is not configured for incident {self.cfg.id!r}; floors: {numbers}")
        sp = served_plan(self.cfg, floor)
        if sp is None:
            return error_response(404, f"floor {floor}: {plan_problem(self.cfg, floor)}")
        try:
            png = await asyncio.get_running_loop().run_in_executor(None, plan_png, sp)
        except Exception as e:  # the file vanished or is corrupt since the config was loaded
            log.warning("plan image of floor %d: %s", floor, e)
            return error_response(404, f"floor {floor}: plan image {sp.source} unreadable: {e}")
        return web.Response(body=png, content_type="image/png", headers={"Cache-Control": "max-age=3600"})


class ConsoleHandle:
    """A running console: ``url``, ``port``, ``board`` (what it knows), ``close()``."""

    def __init__(self, server: ConsoleServer):
        self._server = server

    @property
    def url(self) -> str:
        return self._server.url

    @property
    def port(self) -> int:
        return self._server.port

    @property
    def board(self) -> LiveBoard:
        return self._server.board

    @property
    def server(self) -> ConsoleServer:
        return self._server

    def close(self) -> None:
        self._server.close()

    def __enter__(self) -> ConsoleHandle:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def start_console(session: zenoh.Session, cfg: IncidentConfig, port: int = 8080, host: str = "127.0.0.1",
                  batch_period_s: float = BATCH_PERIOD_S, lost_contact_s: float = LOST_CONTACT_S, *,
                  actor: str = "console", roster: Path | str | None = None, tls=None, https: bool | None = None,
                  origins: list[str] | None = None) -> ConsoleHandle:
    """Serve the console of ``cfg``'s incident on ``host:port`` (port 0: any free port), fed by
    ``session``: one update message per page every ``batch_period_s``; the page raises
    lost_contact for a responder not heard for ``lost_contact_s``.

    Security (:mod:`client.console.auth`): ``actor`` is the identity operator actions are
    published as (the console's certificate name); with ``roster`` operators and viewers log
    in; ``tls`` (a :class:`service.protocol.tls.TlsIdentity`) serves the page over HTTPS, which
    is the default, and required, beyond this machine (``https`` forces it on or off);
    ``origins`` are the addresses the page is opened at (checked against Host and Origin).
    Raises :class:`ConsoleError` when the port cannot be bound or the setup is not safe."""
    if not 0 <= int(port) <= 65535:
        raise ConsoleError(f"port {port} is not a TCP port (0-65535)")
    if not (batch_period_s > 0 and lost_contact_s > 0):
        raise ConsoleError(f"batch_period_s ({batch_period_s}) and lost_contact_s ({lost_contact_s}) must be positive")
    if not wire.is_valid_id(actor):
        raise ConsoleError(f"actor {actor!r} must be an id ([A-Za-z0-9_.-]{{1,64}})")
    local = is_loopback(host)
    if https is None:
        https = not local
    if https and tls is None:
        raise ConsoleError("the console serves beyond this machine over HTTPS only: give it --tls (a console "
                           "certificate whose --san names the address officers open)" if not local else
                           "HTTPS needs --tls (the console's certificate)")
    if not local and roster is None:
        raise ConsoleError(f"--host {host} serves beyond this machine: that needs logins (--tls with the incident "
                           "roster, whose operators and viewers log in)")
    if not local and not https:
        raise ConsoleError(f"--host {host} serves beyond this machine: that needs HTTPS (leave --no-https out)")
    try:
        logins = Logins(Path(roster) if roster is not None else None)
    except ValueError as e:
        raise ConsoleError(str(e)) from None
    server = ConsoleServer(session, cfg, host, int(port), batch_period_s, lost_contact_s, actor=actor, logins=logins,
                           tls=tls, https=https, origins=origins)
    try:
        return ConsoleHandle(server.start())
    except BaseException:
        logins.close()
        raise

"""The console's operator actions: a checkpoint fix, an acknowledged alarm, a roll call or an
evacuation order, a new checkpoint.

A collaborator of :class:`client.console.server.ConsoleServer`, given what it uses: the zenoh
session, the incident's config, this console's actor name, its :class:`client.console.live.LiveBoard`
(a responder's latest device time and floor) and ``broadcast`` (a message to every page). Each action is checked field by field
(:mod:`client.console.requests`: a 4xx naming what is wrong), taken only from an operator's
session (viewers get 403), and published to the service as a
:class:`service.protocol.wire.OperatorAction` on this console's own ``op`` key, naming the
operator; the service records it and answers with an audit.
"""
from __future__ import annotations

import asyncio
import logging
import math
import time

from collections.abc import Callable

import zenoh
from aiohttp import web

from client.console.live import LiveBoard
from client.console.requests import (
    HttpError,
    actor_session,
    error_response,
    finite_number,
    integer,
    read_json,
    responder_id,
)
from service.protocol import wire
from service.protocol.incident import IncidentConfig, UnknownCheckpointError

log = logging.getLogger("firetrack.console")


class OperatorActions:
    """``POST /api/fix``, ``/api/ack``, ``/api/command``, ``/api/checkpoint``."""

    def __init__(self, session: zenoh.Session, cfg: IncidentConfig, actor: str, board: LiveBoard,
                 broadcast: Callable[[dict], None]):
        self.session, self.cfg, self.actor, self.board, self.broadcast = session, cfg, actor, board, broadcast
        self.fixes_sent = 0
        self.commands_sent = 0
        self.added_checkpoints: set[str] = set()  # added here: a service in another process may not know them

    def add_routes(self, router: web.UrlDispatcher) -> None:
        router.add_post("/api/fix", self._fix)
        router.add_post("/api/checkpoint", self._checkpoint)
        router.add_post("/api/command", self._command)
        router.add_post("/api/ack", self._ack)

    def build_fix(self, body: dict, operator: str = "console") -> wire.Fix:
        """A checkpoint Fix from a request body, or :class:`HttpError` saying what is wrong."""
        rid = responder_id(body)
        t = self.board.device_time(rid)
        if t is None:
            raise HttpError(409, f"responder {rid!r} has not been heard by this console yet: a fix is stamped "
                                  "with the responder's latest device time, and there is none")
        sigma = finite_number(body, "sigma", required=False)
        if sigma is not None and not sigma > 0:
            raise HttpError(400, f"'sigma' must be positive (m), got {sigma}")
        name = body.get("name")
        if name is not None:
            if not isinstance(name, str):
                raise HttpError(400, f"'name' must be a checkpoint name, got {name!r}")
            if "x" in body or "y" in body:
                raise HttpError(400, "give a checkpoint 'name' or 'x' and 'y', not both")
            try:
                cp = self.cfg.checkpoint(name)
            except UnknownCheckpointError as e:
                raise HttpError(404, str(e)) from None
            if cp.name not in self.added_checkpoints:  # the service's config file has it: it resolves the name
                return wire.Fix.checkpoint(rid, t, name=cp.name, sigma=sigma, operator=operator)
            # added in this console: a service in another process may not know it, so send where it is
            return wire.Fix.checkpoint(rid, t, x=cp.x, y=cp.y, floor=cp.floor, sigma=sigma or cp.sigma_m,
                                       operator=operator)
        x, y = finite_number(body, "x"), finite_number(body, "y")
        floor = integer(body, "floor")
        if floor is None:
            floor = self.board.floor_of(rid)
        if floor is None:
            raise HttpError(400, f"'floor' is required: responder {rid!r} has no position yet to take it from")
        numbers = [f.number for f in self.cfg.floors]
        if floor not in numbers:
            raise HttpError(400, f"floor {floor} is not configured for incident {self.cfg.id!r}; floors: {numbers}")
        if not self.cfg.within_extent(x, y):
            raise HttpError(422, f"x, y = ({x:.6g}, {y:.6g}) m is {math.hypot(x, y):,.0f} m from the incident's origin, "
                                 f"outside its extent ({self.cfg.extent_m:g} m): check the numbers")
        return wire.Fix.checkpoint(rid, t, x=x, y=y, floor=floor, sigma=sigma, operator=operator)

    async def _publish_action(self, action: wire.OperatorAction) -> str:
        """An operator action to the service, on this console's own key (its certificate's name)."""
        key = wire.key(self.cfg.id, self.actor, "op")
        payload = wire.encode(action)
        await asyncio.get_running_loop().run_in_executor(
            None, lambda: self.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK))
        log.info("console: %s by %s published on %s", action.action, action.operator, key)
        return key

    async def _fix(self, request: web.Request) -> web.Response:
        try:
            who = actor_session(request)
            fix = self.build_fix(await read_json(request), operator=who.user)
        except HttpError as e:
            return error_response(e.status, e.args[0])
        except (ValueError, TypeError, RecursionError) as e:  # a field no check above foresaw (pydantic's are ValueErrors)
            return error_response(400, f"the fix cannot be made from this body: {' '.join(str(e).split())[:300]}")
        key = await self._publish_action(wire.OperatorAction(
            action="fix", operator=who.user, utc=time.time(), responder=fix.responder, fix=wire.encode(fix)))
        self.fixes_sent += 1
        sent = {k: v for k, v in fix.model_dump().items() if v is not None}
        self.broadcast({"type": "fix", "now": time.time(), "fix": sent})
        return web.json_response({"sent": sent, "key": key, "operator": who.user})

    async def _ack(self, request: web.Request) -> web.Response:
        try:
            who = actor_session(request)
            body = await read_json(request)
            rid = responder_id(body)
            alarm = body.get("alarm")
            if not isinstance(alarm, str) or not 0 < len(alarm) <= 64:
                raise HttpError(400, f"'alarm' must be the alarm's kind (e.g. man_down), got {alarm!r}")
        except HttpError as e:
            return error_response(e.status, e.args[0])
        key = await self._publish_action(wire.OperatorAction(action="ack", operator=who.user, utc=time.time(),
                                                             responder=rid, alarm=alarm))
        return web.json_response({"acknowledged": {"responder": rid, "alarm": alarm}, "operator": who.user, "key": key})

    async def _command(self, request: web.Request) -> web.Response:
        """A roll call (``{"action": "par"}``) or an evacuation order (``{"action": "evacuate"}``)
        to every responder this console knows, or to ``"responders": [...]``; each wearable
        acknowledges, and the service's Status says who has not. An operator's action: the
        orders name the operator (``issued_by``), and the console publishes the action on its own
        ``op`` key, the record of who issued it (the orders' keys name the responders only)."""
        try:
            who = actor_session(request)
            body = await read_json(request)
            action = body.get("action")
            if action not in ("par", "evacuate"):
                raise HttpError(400, f"'action' must be 'par' (roll call) or 'evacuate', got {action!r}")
            known = self.board.responders()
            wanted = body.get("responders", known)
            if not isinstance(wanted, list) or not all(isinstance(r, str) and wire.is_valid_id(r) for r in wanted):
                raise HttpError(400, "'responders' must be a list of responder ids")
            if not wanted:
                raise HttpError(409, "no responder is known to this console yet")
        except HttpError as e:
            return error_response(e.status, e.args[0])
        self.commands_sent += 1
        now = time.time()
        order_id = f"{action}-{int(now)}-{self.commands_sent}"
        payloads = [(wire.key(self.cfg.id, rid, "command"),
                     wire.encode(wire.Command(responder=rid, id=order_id, action=action, issued_at=now,
                                              issued_by=who.user))) for rid in wanted]

        def put_all():
            for key, payload in payloads:
                self.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

        await asyncio.get_running_loop().run_in_executor(None, put_all)
        await self._publish_action(wire.OperatorAction(action=action, operator=who.user, utc=now, order=order_id,
                                                       responders=wanted))
        log.info("console: %s %s by %s sent to %d responder(s)", action, order_id, who.user, len(wanted))
        self.broadcast({"type": "command", "now": now, "command": {"id": order_id, "action": action,
                                                                    "responders": wanted, "issued_at": now}})
        return web.json_response({"id": order_id, "action": action, "responders": wanted, "issued_at": now,
                                  "operator": who.user})

    async def _checkpoint(self, request: web.Request) -> web.Response:
        try:
            who = actor_session(request)
            body = await read_json(request)
            name = body.get("name")
            if not isinstance(name, str) or not name.strip():
                raise HttpError(400, f"'name' must be a non-empty text, got {name!r}")
            name = name.strip()
            if any(c.name == name for c in self.cfg.checkpoints):
                raise HttpError(409, f"checkpoint {name!r} exists already")
            x, y = finite_number(body, "x"), finite_number(body, "y")
            floor = integer(body, "floor")
            if floor is None:
                raise HttpError(400, "'floor' is required")
            sigma = finite_number(body, "sigma_m", required=False)
            note = body.get("note")
            if note is not None and not isinstance(note, str):
                raise HttpError(400, f"'note' must be text, got {note!r}")
            try:
                cp = self.cfg.add_checkpoint(name, floor=floor, x=x, y=y, note=note,
                                             **({"sigma_m": sigma} if sigma is not None else {}))
            except (ValueError, TypeError) as e:  # pydantic's ValidationError is a ValueError: a bad field, an unknown floor
                raise HttpError(400, " ".join(str(e).split())[:300]) from None
        except HttpError as e:
            return error_response(e.status, e.args[0])
        self.added_checkpoints.add(cp.name)
        log.info("console: checkpoint %r added at (%.2f, %.2f) floor %d", cp.name, cp.x, cp.y, cp.floor)
        await self._publish_action(wire.OperatorAction(action="checkpoint", operator=who.user, utc=time.time(),
                                                       name=cp.name, x=cp.x, y=cp.y, floor=cp.floor, note=cp.note))
        self.broadcast({"type": "checkpoints", "now": time.time(), "checkpoints": checkpoints_json(self.cfg)})
        return web.json_response({"checkpoint": next(c for c in checkpoints_json(self.cfg) if c["name"] == cp.name)},
                                 status=201)


def checkpoints_json(cfg: IncidentConfig) -> list[dict]:
    """The incident's checkpoints as the page reads them."""
    return [{"name": c.name, "x": c.x, "y": c.y, "floor": c.floor, "sigma_m": c.sigma_m, "note": c.note}
            for c in cfg.checkpoints]

"""What the console's HTTP API accepts: a JSON object within a size, numbers that are finite.

Every handler turns a wrong request into :class:`HttpError` (a 4xx status and a sentence naming
the field and what is wrong with it); :func:`error_response` is the ``{"error": ...}`` reply.
Nothing a client sends reaches Python's JSON parser unbounded: the body is capped at
:data:`POST_MAX_BYTES`, nesting too deep for the parser is a 400 (not a 500 from a
``RecursionError``), and NaN/Infinity, which JSON does not have, are refused.
"""
from __future__ import annotations

import json
import math

from aiohttp import web

from service.protocol import wire

POST_MAX_BYTES = 64 * 1024
SESSION_KEY = web.RequestKey("session", object) if hasattr(web, "RequestKey") else "session"  # aiohttp >= 3.12 wants typed keys


class HttpError(Exception):
    """A request the console refuses: ``status`` (4xx) and the message the client gets."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def error_response(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number JSON has")


def finite_number(body: dict, name: str, required: bool = True) -> float | None:
    """``body[name]`` as a finite float; None when absent and not ``required``."""
    v = body.get(name)
    if v is None:
        if required:
            raise HttpError(400, f"'{name}' is required")
        return None
    try:
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
    except OverflowError:  # an integer beyond any float
        ok = False
    if not ok:
        raise HttpError(400, f"'{name}' must be a finite number, got {str(v)[:40]}")
    return float(v)


def integer(body: dict, name: str) -> int | None:
    """``body[name]`` as an int (not a bool); None when absent."""
    v = body.get(name)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int):
        raise HttpError(400, f"'{name}' must be an integer, got {v!r}")
    return v


def responder_id(body: dict) -> str:
    """``body["responder"]``, a valid responder id."""
    rid = body.get("responder")
    if not isinstance(rid, str) or not wire.is_valid_id(rid):
        raise HttpError(400, f"'responder' must be a responder id ([A-Za-z0-9_.-]{{1,64}}), got {rid!r}")
    return rid


async def read_json(request: web.Request) -> dict:
    """The request's JSON object, or :class:`HttpError` (4xx) for anything else: another
    type, a body over :data:`POST_MAX_BYTES`, bytes that are not UTF-8 JSON, nesting too
    deep to parse (Python's parser recurses), constants JSON does not have (NaN, Infinity)."""
    if request.content_type != "application/json":
        raise HttpError(415, f"send the request as application/json, not {request.content_type or 'no type'}")
    try:
        raw = await request.read()
    except web.HTTPRequestEntityTooLarge:
        raise HttpError(413, f"the body is larger than {POST_MAX_BYTES} bytes") from None
    try:
        body = json.loads(raw.decode("utf-8"), parse_constant=_no_constant)
    except RecursionError:
        raise HttpError(400, "the body is nested too deeply to be a request") from None
    except (ValueError, UnicodeDecodeError) as e:  # JSONDecodeError is a ValueError
        raise HttpError(400, f"the body is not valid JSON: {str(e)[:200]}") from None
    if not isinstance(body, dict):
        raise HttpError(400, f"the body must be a JSON object, got {type(body).__name__}")
    return body


def actor_session(request: web.Request):
    """The session of an operator who may act, or :class:`HttpError` 403 for a viewer."""
    s = request[SESSION_KEY]
    if not s.may_act:
        raise HttpError(403, f"{s.user} is a {s.role}: viewers cannot act (fix, checkpoint, acknowledge, PAR)")
    return s

"""The console's login routes: who is logged in, password and certificate logins, logout.

A collaborator of :class:`client.console.server.ConsoleServer`, given what it needs: the
console's :class:`client.console.auth.Logins`, its incident id and whether it serves HTTPS; the
rules (rosters, throttling, sessions) are :mod:`client.console.auth`'s.
"""
from __future__ import annotations

from aiohttp import web

from client.console.auth import SESSION_COOKIE, Logins
from client.console.requests import SESSION_KEY, HttpError, error_response, read_json


class LoginRoutes:
    """``GET /api/session``, ``POST /api/login``, ``POST /api/logout``."""

    def __init__(self, logins: Logins, incident_id: str, https: bool):
        self.logins, self.incident_id, self.https = logins, incident_id, https

    def add_routes(self, router: web.UrlDispatcher) -> None:
        router.add_get("/api/session", self._session_info)
        router.add_post("/api/login", self._login)
        router.add_post("/api/logout", self._logout)

    def _session_json(self, s) -> dict:
        info = {"auth": "open" if self.logins.open else "required", "user": None, "role": None,
                "incident": self.incident_id, "https": self.https}
        if s is not None:
            info.update(user=s.user, role=s.role, via=s.via)
        return info

    async def _session_info(self, request: web.Request) -> web.Response:
        info = self._session_json(request[SESSION_KEY])
        cert = self._peer_certificate(request)
        if cert is not None and info["user"] is None:
            from service.protocol.pki import certificate_common_name

            info["certificate"] = certificate_common_name(cert)
        return web.json_response(info)

    @staticmethod
    def _peer_certificate(request: web.Request) -> bytes | None:
        sslobj = request.transport.get_extra_info("ssl_object") if request.transport is not None else None
        return sslobj.getpeercert(binary_form=True) if sslobj is not None else None

    async def _login(self, request: web.Request) -> web.Response:
        if self.logins.open:
            return web.json_response(self._session_json(request[SESSION_KEY]))
        address = request.remote or "?"
        if self.logins.throttled(address) == "address":
            return error_response(429, "locked: too many failed logins from this address; wait a minute")
        try:
            body = await read_json(request)
        except HttpError as e:
            return error_response(e.status, e.args[0])
        if body.get("certificate") is True:
            s = self.logins.with_certificate(self._peer_certificate(request), address)
            if s is None:
                return error_response(401, "no client certificate of an operator or viewer of this incident was presented")
        else:
            s, why = await self.logins.login_with_password(body.get("user"), body.get("password"), address)
            if why == "locked":
                return error_response(429, "locked: too many failed logins from this address or for this account; "
                                           "wait, or log in with the client certificate")
            if s is None:
                return error_response(401, "wrong user or password")
        resp = web.json_response(self._session_json(s))
        resp.set_cookie(SESSION_COOKIE, s.token, httponly=True, samesite="Strict", secure=self.https, path="/")
        return resp

    async def _logout(self, request: web.Request) -> web.Response:
        self.logins.logout(request.cookies.get(SESSION_COOKIE))
        resp = web.json_response({"user": None})
        resp.del_cookie(SESSION_COOKIE, path="/")
        return resp

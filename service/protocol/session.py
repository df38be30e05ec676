"""Zenoh session configurations used by every firetrack process.

* The **service** by default *is* the router: one process, an in-process zenoh router
  listening on ``tcp/127.0.0.1:7447`` (``firetrack serve`` with no arguments). With
  ``--connect`` it joins a standalone ``zenohd`` instead (deploy/), as a client.
* **Wearables, the console and tools** are clients that connect to an endpoint.

Multicast scouting is off everywhere: at an incident the router's address is known, and a
laptop must not start talking to whatever else is on the fire service's network.

With a :class:`service.protocol.tls.TlsIdentity` (``--tls DIR``) every session uses mutual
TLS and only TLS: ``tls/`` endpoints (:data:`DEFAULT_TLS_ENDPOINT` by default), the link
protocols restricted to ``tls`` so plain TCP is refused both ways, and a router given an
``access_control`` section (:func:`service.protocol.access.access_control`) enforces it.
Without one, the session is plain TCP with no access control: the one-command demo.
"""
from __future__ import annotations

import json
import re
import socket

import zenoh

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_TLS_ENDPOINT = "tls/127.0.0.1:7447"


def default_endpoint(tls=None) -> str:
    """The local endpoint of the demo (plain TCP), or its TLS twin with ``--tls``."""
    return DEFAULT_TLS_ENDPOINT if tls is not None else DEFAULT_ENDPOINT


def free_local_port() -> int:
    """A TCP port free on 127.0.0.1 now (tests, benchmarks, a console on ``--port 0``)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _base(mode: str, tls=None, listen: bool = False) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if tls is not None:
        conf.insert_json5("transport/link/protocols", json.dumps(["tls"]))
        conf.insert_json5("transport/link/tls", json.dumps(tls.zenoh_tls(listen)))
    return conf


def router_config(listen: list[str] | None = None, tls=None, acl: dict | None = None) -> zenoh.Config:
    """An in-process router listening on ``listen`` (default the local demo endpoint); with
    ``tls`` (a :class:`~service.protocol.tls.TlsIdentity`) mutual TLS only, with ``acl`` (an
    ``access_control`` section) that access control."""
    from service.protocol.tls import check_endpoints

    conf = _base("router", tls, listen=True)
    # no shared memory: a local peer's large messages would have the service map that peer's
    # pool (16 MB each, resident for as long as zenoh keeps the mapping); the wearables are on
    # the network, where it plays no part (tests/test_router_shm.py)
    conf.insert_json5("transport/shared_memory/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps(check_endpoints(listen or [default_endpoint(tls)], tls, "--listen")))
    if acl is not None:
        conf.insert_json5("access_control", json.dumps(acl))
    return conf


def client_config(connect: list[str] | str | None = None, tls=None) -> zenoh.Config:
    """A client session connected to ``connect`` (default the local demo endpoint); with
    ``tls``, mutual TLS only."""
    from service.protocol.tls import check_endpoints

    eps = [connect] if isinstance(connect, str) else (connect or [default_endpoint(tls)])
    conf = _base("client", tls)
    conf.insert_json5("connect/endpoints", json.dumps(check_endpoints(eps, tls, "--connect")))
    return conf


def zenoh_error(e: BaseException) -> str:
    """zenoh's error text in one line for a person: the Rust source location it carries
    (``... at /root/.cargo/git/checkouts/.../tcp.rs:61.``) and its backtrace removed."""
    text = " ".join(str(e).split())
    text = re.sub(r"\s+at\s+\S+\.rs:\d+(:\d+)?\.?", "", text)
    text = re.sub(r"\s*\(?[Bb]acktrace:.*$", "", text)
    return text.strip() or type(e).__name__


def open_session(listen: list[str] | None = None, connect: list[str] | str | None = None, tls=None,
                 acl: dict | None = None) -> zenoh.Session:
    """A router on ``listen`` (the service's default), or a client of ``connect`` that also
    listens on ``listen`` when given; with ``tls`` mutual TLS only, and a router with ``acl``
    enforces that access control. Raises ``ConnectionError`` with one clear line (a
    :class:`~service.protocol.tls.TlsConfigError` for a ``tcp/`` endpoint with TLS)."""
    if isinstance(connect, str):
        connect = [connect]
    if connect:
        conf = client_config(connect, tls)
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(listen))
    else:
        conf = router_config(listen, tls, acl)
    try:
        return zenoh.open(conf)
    except Exception as e:  # zenoh raises its own ZError; say what could not be opened
        where = (f"cannot reach a zenoh router at {', '.join(connect)}" if connect
                 else f"could not listen on {', '.join(listen or [default_endpoint(tls)])}")
        hint = (" (with --tls: is the router on TLS, does its certificate name this address, and is this "
                "certificate from the same incident CA?)" if tls is not None and connect else "")
        raise ConnectionError(f"{where}: {zenoh_error(e)}{hint}") from None


def open_client(connect: list[str] | str | None = None, wait_s: float = 0.0, on_wait=None, tls=None) -> zenoh.Session:
    """A client session to ``connect`` (default the local demo endpoint, its TLS twin with
    ``tls``). A router that is not up yet is retried for up to ``wait_s`` seconds
    (``on_wait(message)`` is told once), then ``ConnectionError`` with one clear line."""
    import time

    deadline = time.monotonic() + max(0.0, wait_s)
    told = False
    while True:
        try:
            return open_session(None, connect or default_endpoint(tls), tls=tls)
        except ConnectionError as e:
            if time.monotonic() >= deadline:
                raise
            if on_wait is not None and not told:
                on_wait(f"{e}; retrying for up to {wait_s:.0f} s ...")
                told = True
            time.sleep(min(0.5, max(0.0, deadline - time.monotonic())))

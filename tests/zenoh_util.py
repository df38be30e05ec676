"""Helpers for tests on a real zenoh router on loopback (free ports, bounded waits)."""
from __future__ import annotations

import time

import zenoh

from service.protocol.session import client_config, router_config
from service.protocol.session import free_local_port as free_port


def router(port: int | None = None, connect: str | None = None) -> tuple[zenoh.Session, str]:
    """An in-process router on a free loopback port, and its endpoint; with ``connect``, linked
    to the router there (a mesh of two)."""
    endpoint = f"tcp/127.0.0.1:{port or free_port()}"
    conf = router_config([endpoint])
    if connect is not None:
        conf.insert_json5("connect/endpoints", f'["{connect}"]')
    return zenoh.open(conf), endpoint


def client(endpoint: str) -> zenoh.Session:
    return zenoh.open(client_config(endpoint))


def wait_until(predicate, timeout: float = 10.0, step: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return predicate()

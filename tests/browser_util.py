"""Debian's Chromium through Playwright for the browser tests: skipped with the reason when
Playwright or the browser is missing."""
from __future__ import annotations

import contextlib
import os
from pathlib import Path

import pytest

CHROMIUM = Path(os.environ.get("FIRETRACK_CHROMIUM", "/usr/bin/chromium"))


def launch_chromium(*args: str):
    """Yield a headless Chromium (``args`` beyond ``--no-sandbox``); stops it afterwards."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e '.[test]')")
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing: install Debian's chromium (.ci/apt-packages.txt) to run the browser tests")
    pw = sync_api.sync_playwright().start()
    try:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=["--no-sandbox", *args])
    except Exception:
        pw.stop()
        raise
    yield b
    b.close()
    pw.stop()


def console_stack():
    """Yield a router on a free port, the demo incident's service and its console on it, a
    client session: ``(service, console, client, cfg, endpoint)``; all closed afterwards."""
    from client.console.server import start_console
    from service.protocol.incident import default_incident
    from service.shell.service import IncidentService, ServiceSettings
    from tests.zenoh_util import client, free_port, router

    session, endpoint = router()
    cfg = default_incident()
    svc = IncidentService(session, cfg, ServiceSettings()).start()
    console = start_console(session, cfg, port=free_port())
    cl = client(endpoint)
    try:
        yield svc, console, cl, cfg, endpoint
    finally:
        console.close()
        cl.close()
        svc.close()
        session.close()


@contextlib.contextmanager
def console_alone(cfg, **settings):
    """Yield a router on a free port, the console of ``cfg`` on it with no service, and a client
    session that puts what a service would: ``(console, client)``; all closed afterwards."""
    from client.console.server import start_console
    from tests.zenoh_util import client, free_port, router

    session, endpoint = router()
    console = start_console(session, cfg, port=free_port(), **settings)
    cl = client(endpoint)
    try:
        yield console, cl
    finally:
        console.close()
        cl.close()
        session.close()

"""A phone is a wearable: the /wear page in a real Chromium, its sensors driven by the DevTools
protocol's overrides, publishing through the console's gateway to a live service on a real
zenoh router on loopback."""
from __future__ import annotations

import time

import pytest

from client.console.server import start_console
from service.protocol.incident import default_incident
from service.shell.service import IncidentService, ServiceSettings
from tests.browser_util import launch_chromium
from tests.phone_util import SENSOR_FLAGS, Phone, enrol
from tests.zenoh_util import client, free_port, router, wait_until


@pytest.fixture(scope="module")
def browser():
    yield from launch_chromium(*SENSOR_FLAGS)


@pytest.fixture(scope="module")
def stack():
    """A router on a free port, the demo incident's service and its console on it, a client session."""
    session, endpoint = router()
    cfg = default_incident()
    svc = IncidentService(session, cfg, ServiceSettings()).start()
    console = start_console(session, cfg, port=free_port())
    cl = client(endpoint)
    yield svc, console, cl, cfg
    console.close()
    cl.close()
    svc.close()
    session.close()


def test_an_enrolled_phone_is_tracked_and_every_frame_is_acknowledged(stack, browser):
    svc, console, cl, cfg = stack
    grant = enrol(console.url, "ff1")
    phone = Phone(browser, console.url, grant["code"])
    try:
        assert phone.js("document.getElementById('who').textContent") == "ff1"
        phone.still()
        phone.start("pocket")
        t0 = time.monotonic()
        while time.monotonic() - t0 < 3.0:  # readings that change, so the sensors fire
            k = time.monotonic() - t0
            phone.reading("accelerometer", 0.1 * (int(k * 50) % 3), 0.0, 9.81)
            phone.reading("gyroscope", 0.0, 0.0, 0.01 * (int(k * 50) % 2))
        assert wait_until(lambda: phone.js("__wear.frames") >= 20, 5)
        phone.page.click("#start")  # stop: the last frame goes out
        sent = phone.js("__wear.link.seq")
        assert phone.wait(f"__wear.link.acked === {sent - 1}", timeout_ms=10_000)
        assert phone.js("__wear.link.pending") == 0
        gw = console.server.phones.stats()
        assert gw["frames"] == sent and gw["refused"] == 0 and gw["duplicates"] == 0, gw
        # the service's own account: every frame taken, none rejected or lost
        assert wait_until(lambda: (console.board.latest("ff1")[1] or {}).get("frames") == sent, 5)
        status = console.board.latest("ff1")[1]
        assert status["rejected"] == {} and status["lost"] == 0, status
        # the console's roster shows the responder
        assert "ff1" in console.board.responders()
    finally:
        phone.close()

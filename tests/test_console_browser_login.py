"""The console with logins in a real browser (Debian's Chromium through Playwright), against a
TLS router with the roster's access control on loopback: an operator logs in, places a fix the
service takes under her name, sees a far fix flagged and reports a PAR; a viewer sees the map
and no actions."""
from __future__ import annotations

import threading
import time

import pytest

from client.console.server import start_console
from service.protocol import wire
from service.protocol.incident import default_incident
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
from tests.test_console_browser import PAGE_TIMEOUT_MS, VIEWPORT, Page, browser  # noqa: F401  (the fixture)
from tests.zenoh_util import wait_until


class LoginPage(Page):
    """A tab that opens at the login form instead of the live page."""

    def __init__(self, browser, url: str):  # noqa: F811
        self.context = browser.new_context(viewport=VIEWPORT)
        self.page = self.context.new_page()
        self.errors: list[str] = []
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.foreign: list[str] = []
        self.page.on("request", lambda r: None if r.url.startswith((url, url.replace("http", "ws", 1), "data:"))
                     else self.foreign.append(r.url))
        self.page.goto(url)
        self.page.locator("#login").wait_for(state="visible", timeout=PAGE_TIMEOUT_MS)

    def log_in(self, user: str, password: str) -> None:
        self.page.fill("#login-user", user)
        self.page.fill("#login-password", password)
        self.page.click("#login-submit")


@pytest.fixture
def secured(tmp_path):
    d = make_pki(tmp_path / "pki")
    with secure_service(d) as (svc, endpoint, tap):
        ff1 = tls_client(endpoint, identity(d, "ff1"))
        session = tls_client(endpoint, identity(d, "console-1"))
        console = start_console(session, default_incident(), port=0, actor="console-1", roster=d / "roster.json")
        stop = threading.Event()

        def walk():  # ff1 placed at the door by its own checkpoint, then walking at twice real time
            frames = walking_frames("ff1", 400.0)
            imu = matched_publisher(ff1, wire.key(INCIDENT, "ff1", "imu"))  # nothing put before the route is lost
            for i, b in enumerate(frames):
                if stop.is_set():
                    return
                imu.put(wire.encode(b))
                if i == 40:
                    wait_until(lambda: svc.received["imu"] == 41, 10)
                    put_routed(ff1, wire.key(INCIDENT, "ff1", "fix"), wire.encode(
                        wire.Fix.checkpoint("ff1", float(b.t[-1]), name=DOOR)))  # a device names a surveyed checkpoint
                time.sleep(0.05)
        walker = threading.Thread(target=walk, daemon=True)
        walker.start()
        try:
            yield svc, console
        finally:
            stop.set()
            walker.join(5)
            console.close()
            session.close()
            ff1.close()


def test_an_operator_logs_in_places_a_fix_sees_a_far_one_flagged_and_reports_a_par(secured, browser):  # noqa: F811
    svc, console = secured
    page = LoginPage(browser, console.url)
    try:
        page.log_in("alice", "not-her-password")
        page.wait("() => document.querySelector('#login-error').textContent.includes('wrong')", timeout_ms=5000)
        page.log_in("alice", PASSWORDS["alice"])
        page.wait("() => window.__firetrack.ready && window.__firetrack.connected")
        assert page.page.locator("#login").is_hidden()
        assert page.page.locator("#who-name").inner_text() == "alice · OPERATOR"
        # the session cookie is out of the page's reach
        assert "firetrack_session" not in page.js("document.cookie")
        assert wait_until(lambda: svc.received["fix"] == 1 and svc.wait_idle(0.1), 20)  # placed at the door
        page.wait("() => { const s = window.__firetrack.snapshot().ff1; return s && s.pose && s.pose.t > 1005; }")
        page.page.locator('#roster tbody tr[data-id="ff1"]').click()

        def metres_per_px() -> float:
            return page.js("(() => { const S = window.__firetrack; const a = S.screenToEnu(0, 0), "
                           "b = S.screenToEnu(1, 0); return Math.hypot(b[0] - a[0], b[1] - a[1]); })()")

        for _ in range(8):  # zoomed in far enough that 4 m is clear of the marker (a click on it selects)
            if 40 * metres_per_px() <= 4.0:
                break
            page.js("(() => { const m = window.__firetrack.map(); m.setZoom(m.getZoom() + 1, {animate: false}); })()")
        assert 40 * metres_per_px() <= 4.0

        def place(dx: float) -> None:
            pose = page.js("window.__firetrack.snapshot().ff1.pose")
            page.click_map_at(pose["x"] + dx, pose["y"])
            page.page.locator("#modal").wait_for(state="visible", timeout=5000)
            page.page.locator("#modal-ok").click()

        def fixes() -> list[dict]:  # the audits of the operator's fixes (a device's fix held out is audited too)
            return [a for a in console.server.audits if a["action"] == "fix"]

        place(4.0)
        assert wait_until(lambda: len(fixes()) >= 1, 15), ("the service did not answer the fix", console.server.audits)
        a = fixes()[0]
        assert (a["actor"], a["operator"], a["action"], a["outcome"], a["flags"]) == (
            "console-1", "alice", "fix", "accepted", [])
        page.wait("() => [...document.querySelectorAll('.toast.ok')].some(e => e.textContent.includes('alice'))",
                  timeout_ms=5000)

        place(86.0)  # the forged-fix distance, this time by an authorised operator: taken, flagged
        assert wait_until(lambda: len(fixes()) >= 2, 15), console.server.audits
        assert fixes()[1]["flags"] == ["implausible_jump"], console.server.audits
        page.wait("() => [...document.querySelectorAll('.toast.error')].some(e => e.textContent.includes('FLAGGED'))",
                  timeout_ms=5000)
        page.wait("() => document.querySelector('#roster tbody tr[data-id=\"ff1\"]').classList.contains('flagged')",
                  timeout_ms=5000)
        assert "FIX FLAGGED" in page.page.locator("#sel-flag").inner_text()

        page.page.locator("#btn-par").click()  # the roll call, issued by alice
        assert wait_until(lambda: any(x["action"] == "par" for x in console.server.audits), 10)
        par = next(x for x in console.server.audits if x["action"] == "par")
        assert (par["operator"], par["outcome"]) == ("alice", "recorded")
        assert svc.responders["ff1"].fixes_flagged == 1
    finally:
        page.close()


def test_a_viewer_sees_the_map_and_no_actions(secured, browser):  # noqa: F811
    svc, console = secured
    page = LoginPage(browser, console.url)
    try:
        page.log_in("vic", PASSWORDS["vic"])
        page.wait("() => window.__firetrack.ready && window.__firetrack.connected")
        assert page.page.locator("#who-name").inner_text() == "vic · VIEWER"
        page.wait("() => { const s = window.__firetrack.snapshot().ff1; return s && s.pose; }")
        for sel in ("#btn-add-cp", "#btn-fix-cp", "#btn-par", "#btn-evacuate"):
            assert page.page.locator(sel).is_hidden(), sel
        pose = page.js("window.__firetrack.snapshot().ff1.pose")
        page.page.locator('#roster tbody tr[data-id="ff1"]').click()
        page.click_map_at(pose["x"] + 3.0, pose["y"])
        time.sleep(0.5)
        assert page.page.locator("#modal").is_hidden()  # no fix to confirm
        assert svc.received["op"] == 0
        page.page.locator("#btn-logout").click()
        page.page.locator("#login").wait_for(state="visible", timeout=PAGE_TIMEOUT_MS)
    finally:
        page.close()

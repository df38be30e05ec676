"""Orders and the man-down prompt on a phone (issue 28), recorded and reprocessed: the /wear page
in a real Chromium against ``firetrack serve --record`` (router, service, recorder, console in
a process of their own); then ``firetrack reprocess`` of the recording."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from service.protocol import wire
from service.review.recording_reader import read_recording
from tests.browser_util import launch_chromium
from tests.phone_util import SENSOR_FLAGS, Phone, collect, enrol, post, serving
from tests.zenoh_util import wait_until

RID = "ff5"
STILL_EVERY_S = 0.01  # s between two settings of the sensors (they fire on a change)


@pytest.fixture(scope="module")
def browser():
    yield from launch_chromium(*SENSOR_FLAGS)


class StillPhone:
    """A phone lying still, as its sensors read: the readings flicker by one quantum (0.1 m/s²,
    0.1 deg/s: a real sensor's noise after the browser's rounding), so they keep firing."""

    def __init__(self, phone: Phone, statuses: list):
        self.phone, self.statuses, self.k = phone, statuses, 0
        self.alarms_seen: list[tuple[float, list[str]]] = []  # (page time, alarms) of each live Status looked at

    def hold(self, until, timeout_s: float, what: str, every_s: float = 0.25):
        """Keep still until ``until()`` is true (looked at every ``every_s``); its value."""
        t0 = last = time.monotonic()
        while True:
            now = time.monotonic()
            if now - last >= every_s or now == t0:
                last = now
                got = until()
                if got:
                    return got
            assert now - t0 < timeout_s, f"not within {timeout_s} s: {what}; {self.diagnosis()}"
            self.k += 1
            self.phone.reading("accelerometer", 0.0, 0.0, 9.8 + 0.1 * (self.k % 2))
            self.phone.reading("gyroscope", 0.0, 0.0, 0.0017 * (self.k % 2))
            time.sleep(STILL_EVERY_S)

    def diagnosis(self) -> str:
        trail = [(round(s.t, 1), s.motion, round(s.motion_since, 1), s.gaps, s.man_down_at and round(s.man_down_at, 1))
                 for s in self.statuses[-40:]]
        return (f"the page's gaps {self.phone.js('__wear.gaps')}, samples {self.phone.js('__wear.samples')}; "
                f"statuses (t, motion, since, gaps, man_down_at) {trail}")

    def status(self) -> wire.Status | None:
        return self.statuses[-1] if self.statuses else None

    def page_now(self) -> float:
        return self.phone.js("performance.now() / 1000")


def test_orders_and_the_man_down_prompt_on_a_phone_are_recorded_and_reprocess_agrees(tmp_path, browser):
    """PAR and EVACUATE are on the page within 2 s of the console's order and their ACKs reach the
    console. Lying still, the phone asks "ARE YOU OK?" with a countdown and the console shows
    no MAN DOWN; a tap cancels it (the answer starts the no-motion clock again); still again and
    no tap, and MAN DOWN is raised at the console. The orders, the ACKs and the answer are in
    the recording, and ``firetrack reprocess`` reaches the live service's end: the same
    acknowledgements, the same answer, man-down."""
    recording = tmp_path / "incident.mcap"
    shots = os.environ.get("FIRETRACK_SCREENSHOTS")  # e.g. docs/screenshots: the README's pictures
    with serving(tmp_path, "--record", str(recording)) as srv:
        base = srv.url.rstrip("/")
        statuses, ssub = collect(srv.client, wire.key(srv.cfg.id, RID, "status"))
        phone = Phone(browser, srv.url, enrol(srv.url, RID)["code"])
        still = StillPhone(phone, statuses)
        try:
            phone.still()
            phone.start("chest")
            still.hold(lambda: still.status() is not None and still.status().frames > 10, 15, "the service hears the phone")
            shown = {}
            for action in ("par", "evacuate"):
                issued = time.time()
                status, order = post(base + "/api/command", {"action": action, "responders": [RID]}, base)
                assert status == 200, order
                still.hold(lambda: phone.js("!document.getElementById('order').hidden"), 5, f"the {action} order on the page")
                got = phone.js("(id) => __wear.orders.find((o) => o.id === id)", order["id"])
                shown[action] = got["shown_at"] - issued
                assert got["action"] == action and shown[action] < 2.0
                if shots and action == "evacuate":
                    phone.page.screenshot(path=f"{shots}/phone-evacuate.png")
                phone.page.click("#order-ack")
                still.hold(lambda: ((still.status().commands.get(action) or {}).get("acked_at") is not None), 5,
                           f"the console hears the {action} ACK")
                assert phone.js("document.getElementById('order').hidden")
            # lying still: asked, the console not alarmed
            asked = still.hold(lambda: not phone.js("document.getElementById('prompt').hidden") and still.status(), 90,
                               "the man-down prompt")
            assert "man_down" not in asked.alarms and asked.man_down_at is not None
            countdown = phone.js("document.getElementById('prompt-count').textContent")
            assert countdown.startswith("MAN DOWN IN ")
            first_due = asked.man_down_at
            # the tap (the sensor feed pauses while it is made: a pause proves no motion, pdr.fleet_kernels.motion_windows)
            phone.page.click("#prompt-ok")
            answered = still.hold(lambda: phone.js("__wear.prompt.log[0].answered_at"), 5, "the answer sent")
            still.hold(lambda: phone.js("document.getElementById('prompt').hidden"), 5, "the prompt gone")
            # past the time man-down was due: the answer cancelled it
            still.hold(lambda: still.status().t > first_due + 5.0, 30, "5 s past the first man-down time")
            assert not any("man_down" in s.alarms for s in statuses), [s.alarms for s in statuses if s.alarms]
            assert still.status().ok_at == pytest.approx(answered, abs=1e-6)
            # still, and no tap this time: asked again, then man-down at the console, and the page says so
            again = still.hold(lambda: not phone.js("document.getElementById('prompt').hidden") and still.status(), 60,
                               "the man-down prompt again")
            if shots:
                phone.page.screenshot(path=f"{shots}/phone-man-down-prompt.png")
            down = still.hold(lambda: "man_down" in still.status().alarms and still.status(), 60, "MAN DOWN at the console")
            # counted from the answer: 30 s still + the state's 4 s lag (the motion state's grid: 0.5 s)
            assert down.motion == "no_motion" and again.man_down_at == down.man_down_at
            assert down.man_down_at == pytest.approx(answered + 34.0, abs=0.6), (
                f"answered {answered:.1f}; {still.diagnosis()}")
            still.hold(lambda: phone.js("document.getElementById('prompt-count').textContent") == "MAN DOWN SENT TO THE CONSOLE",
                       5, "the page says man-down was raised")
            log, phone_gaps = phone.js("__wear.prompt.log"), phone.js("__wear.gaps")
            # the readings stop changing (no more sensor events): the frame in progress goes out
            # and the service takes every frame; man-down stays raised (the prompt covers the page)
            time.sleep(0.5)  # the page sends its frame in progress once the sensors are quiet for 0.2 s
            assert phone.wait("__wear.link.pending === 0 && __wear.link.seq > 0", timeout_ms=10_000)
            sent = phone.js("__wear.link.seq")
            assert wait_until(lambda: still.status().seq == sent - 1, 10), (sent, still.status().seq)
            live = still.status()
            assert "man_down" in live.alarms
        finally:
            ssub.undeclare()
            phone.close()
        assert srv.stop() == 0, srv.log.read_text()[-2000:]
    print(f"\norders on the phone {shown['par']:.2f} s (PAR) and {shown['evacuate']:.2f} s (EVACUATE) after the "
          f"console's; prompts {[{k: round(v, 1) for k, v in p.items() if isinstance(v, float)} for p in log]}; "
          f"answered at {answered:.1f} s, man-down first due {first_due:.1f} s, raised for {down.man_down_at:.1f} s; "
          f"sensor pauses on the page {[round(g['to'] - g['from'], 1) for g in phone_gaps]}")
    # in the recording: both orders, both ACKs and the answer, as the phone sent them
    acks = [wire.decode(m.payload) for m in read_recording(recording, kinds=["ack"], responders=[RID])]
    orders = [wire.decode(m.payload) for m in read_recording(recording, kinds=["command"], responders=[RID])]
    assert sorted(o.action for o in orders) == ["evacuate", "par"]
    assert sorted(a.action for a in acks) == ["evacuate", "ok", "par"]
    assert [a.t for a in acks if a.action == "ok"] == [pytest.approx(answered, abs=1e-6)]
    # reprocess: the same acknowledgements, the same answer, the same man-down as the live service
    out = subprocess.run([sys.executable, "-m", "client.entry", "reprocess", str(recording), "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    mine = json.loads(out.stdout)["responders"][RID]
    assert mine["commands"] == live.commands and all(o["acked_at"] is not None for o in mine["commands"].values())
    assert mine["ok_at"] == pytest.approx(live.ok_at, abs=1e-9)
    assert mine["man_down"] == "man_down" and mine["man_down_at"] == pytest.approx(down.man_down_at, abs=1e-9)

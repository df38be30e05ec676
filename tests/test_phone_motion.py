"""The page's own frame cutting (static/js/wear/motion.js), run in Chromium as the page runs it:
a browser that hands the page a burst of late events a fraction of a millisecond apart does not
get a frame refused by the service's rate check, and a steady stream loses no sample."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from service.protocol import wire
from tests.browser_util import launch_chromium

STATIC = Path(__file__).resolve().parents[1] / "client" / "console" / "static"
ORIGIN = "http://phone.test"


@pytest.fixture(scope="module")
def browser():
    yield from launch_chromium()


@pytest.fixture(scope="module")
def page(browser):
    p = browser.new_page()
    # the page's modules as the console serves them (ES modules need http, not file://)
    p.route(f"{ORIGIN}/**", lambda route: route.fulfill(
        status=200, content_type="text/javascript" if route.request.url.endswith(".js") else "text/html",
        body=(STATIC / route.request.url[len(ORIGIN) + 1:]).read_text() if route.request.url.endswith(".js")
        else "<!DOCTYPE html><title>motion</title>"))
    p.goto(f"{ORIGIN}/motion.html")
    p.evaluate(f"async () => {{ window.M = await import('{ORIGIN}/js/wear/motion.js'); }}")
    yield p
    p.close()


def _cut(page, t: np.ndarray, min_interval_s: float | None = None) -> tuple[list[dict], dict]:
    """The frames motion.js's FrameCutter makes of samples at times ``t`` (a still phone), and its counts."""
    return page.evaluate("""([ts, minI]) => {
        const c = minI === null ? new M.FrameCutter() : new M.FrameCutter(M.FRAME_S, minI), out = [];
        for (const t of ts) { const f = c.push({t, acc: [0, 0.1, 9.8], gyr: [0, 0, 0.0017], mag: null}); if (f) out.push(f); }
        const last = c.flush(); if (last) out.push(last);
        return [out, {dropped: c.dropped, bunched: c.bunched, minInterval: M.MIN_INTERVAL_S}]; }""",
                         [t.tolist(), min_interval_s])


def _refused(frames: list[dict]) -> list[str]:
    """What the wire schema (the service's checks) says of each frame that it refuses."""
    out = []
    for k, f in enumerate(frames):
        try:
            wire.ImuBatch(responder="ff1", device="phone", seq=k, t=np.array(f["t"]), acc=np.array(f["acc"]),
                          gyr=np.array(f["gyr"]))
        except ValueError as e:
            out.append(" ".join(str(e).split())[:160])
    return out


def _bursty(seconds: float = 20.0, hz: float = 60.0, seed: int = 3) -> np.ndarray:
    """A 60 Hz stream whose page is busy for 150 ms every 2 s, then handles the events it missed
    at once: 9 events 0.1 ms apart (the burst that made the gate refuse frames)."""
    rng = np.random.default_rng(seed)
    t = list(np.arange(0.0, seconds, 1.0 / hz) + rng.normal(0, 0.002, int(seconds * hz)))
    for busy in np.arange(1.0, seconds - 1.0, 2.0):
        t = [x for x in t if not busy <= x < busy + 0.15] + [busy + 0.15 + 1e-4 * i for i in range(9)]
    return 5.0 + np.sort(np.asarray(t))


def test_a_burst_of_late_events_is_thinned_so_the_gate_refuses_no_frame(page):
    t = _bursty()
    frames, counts = _cut(page, t)
    assert _refused(frames) == [] and counts["bunched"] >= 9 * 8  # 8 of each burst of 9 dropped, counted
    kept = np.concatenate([f["t"] for f in frames])
    assert np.diff(kept).min() >= counts["minInterval"] - 1e-12
    # the control: the same events without the rule, and the service refuses frames for their rate
    raw, _ = _cut(page, t, 0.0)
    refused = _refused(raw)
    assert refused and all("rate" in r for r in refused), refused


@pytest.mark.parametrize("hz", [30.0, 60.0, 200.0])
def test_a_steady_stream_with_jitter_loses_no_sample(page, hz):
    rng = np.random.default_rng(int(hz))
    t = 3.0 + np.cumsum(np.clip(1.0 / hz + rng.normal(0, 0.1 / hz, int(10 * hz)), 0.6 / hz, None))
    frames, counts = _cut(page, t)
    assert counts["bunched"] == 0 and counts["dropped"] == 0 and _refused(frames) == []
    assert np.array_equal(np.concatenate([f["t"] for f in frames]), t)

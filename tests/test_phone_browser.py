"""A phone is a wearable: the /wear page in a real Chromium, its sensors driven by the DevTools
protocol's overrides, publishing through the console's gateway to a live service on a real
zenoh router on loopback."""
from __future__ import annotations

import dataclasses
import os
import time

import numpy as np
import pytest

from pdr.io import load
from pdr.recording import Landmarks, Series
from service.protocol import wire
from service.review.ipin_run import run_ipin
from tests.browser_util import console_stack, launch_chromium
from tests.conftest import shared_data_path
from tests.phone_util import SENSOR_FLAGS, Feed, Phone, collect, enrol, serving
from tests.zenoh_util import wait_until


@pytest.fixture(scope="module")
def browser():
    yield from launch_chromium(*SENSOR_FLAGS)


@pytest.fixture(scope="module")
def stack():
    for svc, console, cl, cfg, _ in console_stack():
        yield svc, console, cl, cfg


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


def test_the_console_enrols_a_phone_with_a_qr_code_and_shows_it_in_the_roster(stack, browser):
    """The operator selects a roster row, presses ENROL PHONE and reads the code off the console;
    the phone joins with it; the console's roster shows the responder heard."""
    svc, console, cl, cfg = stack
    rid = cfg.roster[0].id if cfg.roster else "ff1"
    ctx = browser.new_context(viewport={"width": 1400, "height": 850})
    page = ctx.new_page()
    try:
        page.goto(console.url)
        page.wait_for_function("window.__firetrack && window.__firetrack.ready", timeout=15_000)
        page.evaluate("(id) => window.__firetrack.select(id)", rid)
        page.click("#btn-phone")
        page.wait_for_selector("#phone-enrol:not([hidden]) #phone-qr svg", timeout=10_000)
        code = page.text_content("#phone-code")
        assert len(code) == 6 and page.text_content("#phone-url").endswith("/wear")
        page.click("#phone-close")
        phone = Phone(browser, console.url, code)
        try:
            assert phone.js("document.getElementById('who').textContent") == rid
            phone.still()
            phone.start("hand")
            _walking(phone, 2.0)
            page.wait_for_function(f"(() => {{ const r = document.querySelector('#roster tr[data-id=\"{rid}\"]');"
                                   f" return r && !r.classList.contains('unheard'); }})()", timeout=10_000)
        finally:
            phone.close()
    finally:
        ctx.close()


def _walking(phone: Phone, seconds: float) -> None:
    """Readings that change (a phone's sensors fire on a change): a 2 Hz bounce on z."""
    t0 = time.monotonic()
    while (k := time.monotonic() - t0) < seconds:
        phone.reading("accelerometer", 0.3, 0.1, 9.81 + 2.0 * np.sin(2 * np.pi * 2.0 * k))
        phone.reading("gyroscope", 0.0, 0.0, 0.05 * np.sin(2 * np.pi * 1.0 * k))


def test_rotation_rates_of_device_motion_events_are_converted_from_degrees(stack, browser):
    """Chromium's devicemotion events under a gyroscope override: rotationRate is in deg/s and
    the page's motion.js gives rad/s in the body frame (alpha about x, beta about y, gamma
    about z); the accelerometer keeps its axes and sign. Taking deg/s as rad/s fails here."""
    svc, console, cl, cfg = stack
    phone = Phone(browser, console.url, enrol(console.url, "ffdeg")["code"])
    try:
        phone.js("""() => { window.__events = [];
            addEventListener('devicemotion', (e) => window.__events.push({raw: [e.rotationRate.alpha, e.rotationRate.beta, e.rotationRate.gamma],
                conv: window.__motion.fromDeviceMotion(e)})); }""")
        phone.js("async () => { window.__motion = await import('/static/js/wear/motion.js'); }")
        gyr, acc = (0.8, -0.5, 0.25), (1.2, -0.7, 9.6)  # rad/s, m/s²
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.0:
            phone.reading("gyroscope", *gyr)
            phone.reading("accelerometer", *acc)
        phone.wait("window.__events.filter((e) => e.conv).length > 5")
        last = phone.js("window.__events.filter((e) => e.conv).pop()")
    finally:
        phone.close()
    # the browser's own unit and order: degrees per second, alpha about x, beta about y, gamma about z
    np.testing.assert_allclose(last["raw"], np.degrees(gyr), atol=0.2)
    np.testing.assert_allclose(last["conv"]["gyr"], gyr, atol=np.radians(0.2))  # quantised to 0.1 deg/s
    np.testing.assert_allclose(last["conv"]["acc"], acc, atol=0.1)  # quantised to 0.1 m/s²


def test_ten_seconds_offline_lose_no_frame(stack, browser):
    """The phone loses its network for 10 s (DevTools network emulation) while it walks on:
    it keeps its frames, reconnects, sends them again, and the service takes every one."""
    svc, console, cl, cfg = stack
    phone = Phone(browser, console.url, enrol(console.url, "ffoff")["code"])
    try:
        phone.still()
        phone.start("hand")
        _walking(phone, 2.0)
        phone.cdp.send("Network.enable")
        phone.cdp.send("Network.emulateNetworkConditions",
                       {"offline": True, "latency": 0, "downloadThroughput": -1, "uploadThroughput": -1})
        _walking(phone, 10.0)
        offline = phone.js("({pending: __wear.link.pending, ready: __wear.link.ready, text: document.getElementById('link').textContent})")
        phone.cdp.send("Network.emulateNetworkConditions",
                       {"offline": False, "latency": 0, "downloadThroughput": -1, "uploadThroughput": -1})
        _walking(phone, 2.0)
        phone.page.click("#start")
        sent = phone.js("__wear.link.seq")
        assert phone.wait(f"__wear.link.acked === {sent - 1}", timeout_ms=20_000)
        counts = phone.js("__wear.link.counts")
    finally:
        phone.close()
    assert wait_until(lambda: (console.board.latest("ffoff")[1] or {}).get("frames") == sent, 5)
    status = console.board.latest("ffoff")[1]
    print(f"\noffline: {offline}; {sent} frames, phone counts {counts}; service lost {status['lost']}, "
          f"rejected {status['rejected']}")
    # the frames of the 10 s (10 a second when the browser keeps up; fewer on a loaded machine) waited on the phone
    assert offline["pending"] >= 50 and not offline["ready"]
    assert counts["resent"] >= 50 and counts["reconnects"] >= 1
    assert status["lost"] == 0 and status["rejected"] == {} and status["frames"] == sent


IPIN_WALK = "ipin2023/IPIN2023_T3_TrainingTrial04_repetition01.txt.gz"
STRETCH_S = (50.0, 162.0)  # s after the walk's first sample: landmarks 0 (the start fix) to 13, 106 steps
LEAD_IN_S = 5.0  # s of the walk played before the stretch (not scored): the page's sampling settles
# (15 s before issue 30's suite time; with 5 s: 0.2 s of pauses over 0.1 s, 106 steps live and in the file)
# How far the tracked walk may be from the file's: the 2 % and 0.5 m. The walk is one
# whose tracking a browser's way of sampling does not move by itself (tests/test_phone_walk_choice.py:
# the file read at the ticks of an uneven 58 Hz timer, as Chromium reads it, rounded, with a 10 Hz
# magnetometer, gives this stretch's p75 within 0.25 m of the file's and its steps within one). On TrainingTrial01_repetition01,
# the walk this test played before, the same resampling loses 2 of 88 steps in a third of the draws
# and the p75 over its 6 landmarks jumps by 1 m: the PDR's step detector, not the page.
STEP_TOLERANCE = 0.02
P75_TOLERANCE_M = 0.5


def _cut(s, a, b):
    m = (s.t >= a) & (s.t <= b)
    return Series(s.t[m], s.values[m])


def _stretch(rec, a, b):
    """The recording between device times a and b, without pressure (a phone's browser gives
    none), GNSS or the phone's own orientation."""
    lm = rec.landmarks
    m = (lm.t >= a) & (lm.t <= b)
    landmarks = Landmarks(lm.t[m], lm.lat[m], lm.lon[m], lm.floor[m], lm.counter[m])
    cut = {k: _cut(getattr(rec, k), a, b) for k in ("acc", "gyr", "mag")}
    return dataclasses.replace(rec, **cut, pressure=None, gnss=None, landmarks=landmarks,
                               orientation_ref=None, device_orientation=None)


def _signal_error(t, values, series, lags=np.arange(0.0, 0.0334, 0.002)) -> float:
    """Median absolute difference between samples at times t and the series interpolated at
    t - lag, for the lag (the browser samples a reading after it was set) that fits best."""
    def err(lag):
        ref = np.column_stack([np.interp(t - lag, series.t, series.values[:, k]) for k in range(3)])
        return float(np.median(np.abs(values - ref)))
    return round(min(err(lag) for lag in lags), 3)


def _summary(run) -> tuple[int, float]:
    return len(run.diagnostics["steps"]["t"]), float(np.percentile(run.errors("live").error_m, 75))


@pytest.fixture
def served(tmp_path):
    with serving(tmp_path) as srv:
        yield srv.url, srv.client, srv.cfg


@pytest.mark.recording
def test_a_real_ipin_walk_played_into_the_phones_sensors_tracks_like_the_recording(served, browser):
    """112 s of a development IPIN walk (after a 5 s lead-in) played into Chromium's sensor
    overrides at the recording's pace; the page's frames, as the service received them, tracked by the offline
    pipeline (landmark 0 as the start fix, no GNSS, no barometer) give the steps of the same
    stretch of the file within 2 %, and landmark errors (p75) within 0.5 m; every frame is
    acknowledged, none rejected or lost; the console's roster shows the responder; the position
    reaches the service as GNSS fixes with their stated accuracy."""
    url, cl, cfg = served
    rec = load(shared_data_path(IPIN_WALK))
    a, b = rec.acc.t[0] + STRETCH_S[0], rec.acc.t[0] + STRETCH_S[1]
    # the file's own figures first: this also compiles the pipeline's kernels, which would
    # otherwise hold this process (and the feed) up for seconds while the phone walks
    ref_steps, ref_p75 = _summary(run_ipin(_stretch(rec, a, b), cfg, fix_every=0, use_gnss=False))
    frames, sub = collect(cl, wire.key(cfg.id, "ff3", "imu"))
    fixes, fsub = collect(cl, wire.key(cfg.id, "ff3", "fix"))
    statuses, ssub = collect(cl, wire.key(cfg.id, "ff3", "status"))
    phone = Phone(browser, url, enrol(url, "ff3")["code"])
    try:
        phone.still()
        phone.start("hand")
        feed = Feed(phone, rec, a - LEAD_IN_S, b)  # the lead-in warms the live pipeline up for the new responder
        feed.run()
        phone.page.click("#start")  # stop: the frame in progress goes out
        sent = phone.js("__wear.link.seq")
        # what the page itself set aside: samples out of order, bunched events, gaps over 0.5 s
        page_counts = phone.js("({dropped: __wear.cutter.dropped, bunched: __wear.cutter.bunched, gaps: __wear.gaps.length,"
                               " samples: __wear.samples})")
        assert phone.wait(f"__wear.link.acked === {sent - 1}", timeout_ms=20_000), "not every frame was acknowledged"
        assert wait_until(lambda: len(frames) >= sent and statuses and statuses[-1].frames == sent, 5)
        status = statuses[-1]
        frame_rejects = {k: n for k, n in status.rejected.items() if not k.startswith("fix_")}
        assert frame_rejects == {} and status.lost == 0, status  # GNSS fixes the indoor gates judge
        judged = {k: n for k, n in status.rejected.items() if k.startswith("fix_")}
        live_steps = status.steps
        # the console's roster (its page) shows the responder heard
        page = browser.new_page()
        page.goto(url)
        page.wait_for_function("(() => { const r = document.querySelector('#roster tr[data-id=\"ff3\"]');"
                               " return r && !r.classList.contains('unheard'); })()", timeout=15_000)
        page.close()
    finally:
        for s in (sub, fsub, ssub):
            s.undeclare()
        phone.close()
    got = sorted({f.seq: f for f in frames}.values(), key=lambda f: f.seq)
    assert [f.seq for f in got] == list(range(sent))
    # the page's clock to the file's: UTC = t + utc_offset, file time = UTC - w0 + f0
    shift = float(np.median([f.utc_offset for f in got])) - feed.w0 + feed.f0
    t = np.concatenate([f.t for f in got]) + shift
    dt = np.diff(t[(t >= a) & (t <= b)])
    stalled = float(dt[dt > 0.1].sum())  # s the browser gave no sample (a starved renderer or feeder)
    assert stalled < 0.02 * (b - a), (f"the browser sampled the sensors with {int((dt > 0.1).sum())} pauses over "
                                      f"0.1 s, {stalled:.1f} s of {b - a:.0f} s: this machine did not keep the "
                                      f"recording's pace (load {os.getloadavg()[0]:.0f}; the feeder itself "
                                      f"stalled {len(feed.stalls)} times, {sum(s for _, s in feed.stalls):.1f} s, "
                                      f"at {[round(at) for at, _ in feed.stalls]} s)")
    acc, gyr = np.concatenate([f.acc for f in got]), np.concatenate([f.gyr for f in got])
    with_mag = [f for f in got if f.mag is not None]
    mag = Series(np.concatenate([f.t for f in with_mag]) + shift, np.concatenate([f.mag for f in with_mag]))
    phone_rec = _stretch(dataclasses.replace(rec, acc=Series(t, acc), gyr=Series(t, gyr), mag=mag), a, b)
    steps, p75 = _summary(run_ipin(phone_rec, cfg, fix_every=0, use_gnss=False))
    inside = (t >= a) & (t <= b)
    rate = (inside.sum() - 1) / (b - a)
    fidelity = {name: _signal_error(t[inside], v[inside], s) for name, v, s in (
        ("acc m/s²", acc, rec.acc), ("gyr deg/s", np.degrees(gyr), Series(rec.gyr.t, np.degrees(rec.gyr.values))))}
    print(f"\nphone: {sent} frames, {inside.sum()} samples in the stretch at {rate:.1f} Hz, {feed.calls} sensor "
          f"overrides, {stalled:.1f} s of pauses over 0.1 s, {len(fixes)} GNSS fixes ({judged} refused by the service's gates); the file's signal "
          f"reproduced within {fidelity}; steps {steps} (live {live_steps}, with the lead-in) vs {ref_steps} in the "
          f"file; landmark p75 {p75:.2f} m vs {ref_p75:.2f} m; the page set aside {page_counts}")
    assert page_counts["dropped"] == 0  # (a gap is this machine stalling the feed: the pause check above judges it)
    # the page's samples are the file's, in the same units and axes, on the file's clock: the
    # median error is within the browser's quantisation (0.1 m/s², 0.1 deg/s) plus a poll's lag
    # (the gyroscope's 100 Hz samples change more between polls; deg/s taken as rad/s would be ~57x)
    assert fidelity["acc m/s²"] < 0.1 and fidelity["gyr deg/s"] < 1.0, fidelity
    assert abs(steps - ref_steps) <= STEP_TOLERANCE * ref_steps
    assert abs(p75 - ref_p75) <= P75_TOLERANCE_M
    # the position reached the service as GNSS fixes with their stated accuracy
    stated = set(np.round(rec.gnss.accuracy_m[(rec.gnss.t >= feed.f0) & (rec.gnss.t <= b)], 3))
    assert fixes and all(f.source == "gnss" and round(f.accuracy, 3) in stated for f in fixes), (stated, fixes[:3])

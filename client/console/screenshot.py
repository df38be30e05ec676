"""The README's picture of the console: ``python -m client.console.screenshot docs/console.png``.

A real demo, not a mock-up: a zenoh router on a free loopback port, the service of the demo
incident (the IPIN museum), its console, and simulated responders
(:class:`pdr.simulation.WalkerFleet`) whose raw IMU and barometer frames go through the
service's pipelines. Each is placed by a checkpoint fix at its true start, some get a fix
from a tag reader every ``fix_every_s``, so their ellipses differ; one collapses and lies
still long enough for the man-down alarm. Debian's Chromium (headless, through Playwright)
takes the picture.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from service.protocol.session import free_local_port

CHROMIUM = "/usr/bin/chromium"
FRAME_S = 0.1  # device seconds per IMU frame, as a wearable sends them


def take_screenshot(out: Path, walkers: int = 7, seconds: float = 75.0, collapse_at: float = 30.0,
                    fix_every_s: float = 20.0, seed: int = 4, size: tuple[int, int] = (1600, 900),
                    chromium: str = CHROMIUM) -> Path:
    """Run the demo for ``seconds`` of device time (fast, then the last seconds live) and save
    the console as PNG at ``out``."""
    from playwright.sync_api import sync_playwright

    from client.console.server import start_console
    from client.wearable import Wearable
    from pdr.simulation import WalkerFleet
    from service.protocol import wire
    from service.protocol.incident import default_incident
    from service.protocol.session import open_client, open_session
    from service.shell.service import IncidentService

    cfg = default_incident()
    endpoint = f"tcp/127.0.0.1:{free_local_port()}"
    session = open_session([endpoint])
    svc = IncidentService(session, cfg).start()
    console = start_console(session, cfg, port=free_local_port())
    cl = open_client(endpoint)
    names = [f"E{k + 1}-{n}" for k, n in enumerate(["Weber", "Kaya", "Novak", "Schmidt", "Rossi", "Berg", "Lang",
                                                    "Hahn", "Vogel"][:walkers])]
    # inside the museum's surveyed area, ground floor (the checkpoints t01-* and t52-lm1 lie there)
    fleet = WalkerFleet(walkers, seed=seed, bounds=(-48.0, 8.0, -26.0, 22.0), floors=(0, 0), responders=names,
                        start_t=1000.0, attitude=False)
    fleet.collapse(walkers - 1, at=1000.0 + collapse_at)
    wearables = {r: Wearable(cl, cfg.id, r) for r in names}
    per = int(round(FRAME_S * fleet.rate_hz))
    seq = 0
    next_fix = np.zeros(walkers)  # device time of each walker's next tag-reader fix (0: place it now)

    def advance(live: bool) -> None:
        nonlocal seq
        b = fleet.next_arrays(per)
        for i, r in enumerate(names):
            m = b.pressure_mask[i]
            wearables[r].send("imu", wire.ImuBatch(
                responder=r, device=f"phone-{r}", seq=seq, t=b.t[i], acc=b.acc[i], gyr=b.gyr[i], mag=b.mag[i],
                pressure_t=b.t[i][m], pressure=b.pressure[i][m], carry="handheld"))
            t_end = float(b.t[i, -1])
            if t_end >= next_fix[i]:  # the door's tag reader (every other walker has none after the entry)
                wearables[r].send("fix", wire.Fix.checkpoint(r, t_end, x=float(b.x[i, -1]), y=float(b.y[i, -1]),
                                                             floor=0, sigma=0.5, operator="tag reader"))
                next_fix[i] = t_end + fix_every_s if i % 2 == 0 else np.inf
        seq += 1
        if live:
            time.sleep(FRAME_S)

    try:
        fast = int((seconds - 4.0) / FRAME_S)
        for k in range(fast):
            advance(False)
            if k % 50 == 49:  # let the service keep up (frames before fixes, as live)
                svc.wait_idle(30.0)
        svc.wait_idle(60.0)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, headless=True, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": size[0], "height": size[1]})
            page.goto(console.url)
            page.wait_for_function("window.__firetrack && window.__firetrack.ready && window.__firetrack.connected",
                                   timeout=20_000)
            page.wait_for_function("window.__firetrack.planLoaded === true", timeout=30_000)
            for _ in range(int(4.0 / FRAME_S)):  # the last seconds live, with the page watching
                advance(True)
            page.wait_for_function("window.__firetrack.alarmList().some(a => a.kind === 'man_down')", timeout=10_000)
            page.evaluate("window.__firetrack.fitResponders()")
            page.evaluate(f"window.__firetrack.select({names[1]!r})")
            page.evaluate("window.__firetrack.fitResponders()")
            time.sleep(0.8)  # one roster refresh and a few frames
            out.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(out))
            browser.close()
    finally:
        for w in wearables.values():
            w.close()
        console.close()
        cl.close()
        svc.close()
        session.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, nargs="?", default=Path("docs/console.png"))
    ap.add_argument("--walkers", type=int, default=7)
    ap.add_argument("--seconds", type=float, default=75.0)
    args = ap.parse_args()
    print(take_screenshot(args.out, walkers=args.walkers, seconds=args.seconds))


if __name__ == "__main__":
    main()

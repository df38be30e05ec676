"""docs/INTEGRATING.md works as written: its example, run as a separate process against a live
service, publishes a GNSS fix stamped in UTC and a UWB range stamped in device time (both
applied) and a GNSS fix from the future (rejected, and counted as such)."""
from __future__ import annotations

import math
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack

from client.simulate import SimulationPublisher, building_bounds
from service.protocol import wire
from service.protocol.incident import default_incident, incident_from_dict
from service.shell.service import IncidentService, ServiceSettings
from tests.zenoh_util import client, router, wait_until

ROOT = Path(__file__).resolve().parents[1]
ANCHOR = {"id": "A1", "x": 0.0, "y": 0.0, "z": 3.0, "floor": 0}


def _example(tmp_path) -> Path:
    text = (ROOT / "docs" / "INTEGRATING.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    assert len(code.strip().splitlines()) <= 30, "the example is meant to stay short"
    path = tmp_path / "publish_fixes.py"
    path.write_text(code)
    return path


def test_the_integrators_example_publishes_fixes_that_are_applied_or_rejected_with_a_reason(tmp_path):
    base = default_incident()
    data = base.model_dump(mode="json")
    data["uwb_anchors"] = [ANCHOR]
    cfg = incident_from_dict(data, base_dir=getattr(base, "_base_dir", ROOT))
    session, endpoint = router()
    svc = IncidentService(session, cfg, ServiceSettings()).start()
    cl = client(endpoint)
    truth = {}
    sub = cl.declare_subscriber(wire.key(cfg.id, "sim-000", "truth"),
                                lambda s: truth.update(msgpack.unpackb(s.payload.to_bytes())))
    pub = SimulationPublisher(cl, cfg.id, 1, rate_hz=50.0, seed=11, bounds=building_bounds(cfg))
    stop = threading.Event()
    walker = threading.Thread(target=pub.run, args=(90.0, stop), daemon=True)
    walker.start()
    try:
        assert wait_until(lambda: truth.get("steps", 0) > 15, 30), "the simulated responder did not walk"
        x, y = truth["x"], truth["y"]
        lat, lon, _ = cfg.to_geodetic(x, y)
        rng = math.sqrt(x * x + y * y + (ANCHOR["z"] - cfg.uwb_tag_height_m) ** 2)  # 3D: the anchor is 3 m up
        proc = subprocess.run([sys.executable, str(_example(tmp_path)), endpoint, cfg.id, "sim-000", repr(lat),
                               repr(lon), "A1", repr(rng)], capture_output=True, text=True, timeout=60, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert "applied 2 queued 0" in proc.stdout, proc.stdout + proc.stderr[-1000:]
        assert "rejected {'fix_future': 1}" in proc.stdout, proc.stdout
    finally:
        stop.set()
        walker.join(10)
        pub.close()
        sub.undeclare()
        cl.close()
        r = svc.responders.get("sim-000")
        svc.close()
        session.close()
    st = svc.core.status_of(r, time.time())
    assert st.rejected.get("fix_future") == 1 and st.fixes["applied"] >= 3  # the door checkpoint, GNSS, UWB

"""Foxglove: the exported MCAP decodes with its own Foxglove schemas; the live server serves LocationFix.

One live incident (a real zenoh router on loopback, the service recording, the live Foxglove
server, two simulated walkers of which one collapses, an operator acknowledging the alarm)
feeds both tests: a WebSocket client speaking Foxglove's protocol subscribes while they
walk, and the recording is reprocessed and exported afterwards.
"""
from __future__ import annotations

import base64
import json
import math
import threading
import time

import numpy as np
import pytest

foxglove = pytest.importorskip("foxglove", reason="the [foxglove] extra (foxglove-sdk) is not installed")
websockets_sync = pytest.importorskip("websockets.sync.client", reason="the websockets package is not installed")
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402
from google.protobuf import unknown_fields as pb_unknown  # noqa: E402

from client.wearable import Wearable  # noqa: E402
from service.protocol import wire  # noqa: E402
from service.protocol.incident import default_incident  # noqa: E402
from service.review.recorder import IncidentRecorder  # noqa: E402
from service.shell.foxglove_live import FoxgloveLive  # noqa: E402
from service.shell.service import IncidentService, ServiceSettings  # noqa: E402
from tests.walkers import walk  # noqa: E402
from tests.zenoh_util import client, router, wait_until  # noqa: E402

WALKER, FALLEN = "walker", "fallen"
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")


def message_class(schema_name: str, fds: bytes):
    """The protobuf class of ``schema_name`` from a FileDescriptorSet (files added once their imports are)."""
    pool = descriptor_pool.DescriptorPool()
    files = list(descriptor_pb2.FileDescriptorSet.FromString(fds).file)
    added: set[str] = set()
    while files:
        ready = [f for f in files if set(f.dependency) <= added]
        assert ready, f"{schema_name}: the descriptor set's imports cannot be resolved"
        for f in ready:
            pool.Add(f)
            added.add(f.name)
            files.remove(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def decode_strictly(cls, data: bytes):
    """The message, checked: nothing the schema does not know, and it survives a round trip."""
    msg = cls.FromString(data)
    assert len(pb_unknown.UnknownFieldSet(msg)) == 0, f"{cls.DESCRIPTOR.full_name}: fields outside its schema"
    assert cls.FromString(msg.SerializeToString()) == msg
    return msg


def foxglove_schema_names() -> set[str]:
    import foxglove.messages as fm

    return {getattr(fm, n).get_schema().name for n in dir(fm) if hasattr(getattr(fm, n), "get_schema")}


class FoxgloveClient:
    """A client of Foxglove's WebSocket protocol: reads the advertisements, subscribes to a topic, returns messages."""

    def __init__(self, url: str):
        # foxglove-sdk's server (0.30) answers only the protocol's new name, foxglove.sdk.v1: the same
        # messages as foxglove.websocket.v1 under another name. A client offers both, as Foxglove does.
        self._connection = websockets_sync.connect(url, subprotocols=list(SUBPROTOCOLS), open_timeout=10)
        self.ws = self._connection.__enter__()
        assert self.ws.subprotocol in SUBPROTOCOLS
        self.channels: dict[str, dict] = {}
        self.subscribed: dict[int, dict] = {}

    def _read(self, timeout: float):
        frame = self.ws.recv(timeout=timeout)
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg["op"] == "advertise":
                self.channels.update({c["topic"]: c for c in msg["channels"]})
            return None
        assert frame[0] == 0x01, f"opcode {frame[0]}"  # message data: sub id (u32), log time (u64), payload
        sub = int.from_bytes(frame[1:5], "little")
        return self.subscribed[sub], int.from_bytes(frame[5:13], "little"), frame[13:]

    def first_message(self, topic: str, timeout: float = 30.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if topic in self.channels and not any(c["topic"] == topic for c in self.subscribed.values()):
                sub = len(self.subscribed) + 1
                self.subscribed[sub] = self.channels[topic]
                self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": sub, "channelId": self.channels[topic]["id"]}]}))
            try:
                got = self._read(max(0.05, deadline - time.monotonic()))
            except TimeoutError:
                break
            if got is not None and got[0]["topic"] == topic:
                return got
        raise AssertionError(f"no message on {topic} within {timeout} s; advertised: {sorted(self.channels)}")

    def close(self):
        self._connection.__exit__(None, None, None)


@pytest.fixture(scope="module")
def incident_run(tmp_path_factory):
    """A recorded live incident with the Foxglove server; what the WebSocket client received."""
    cfg = default_incident()
    path = tmp_path_factory.mktemp("foxglove") / "incident.mcap"
    session, endpoint = router()
    recorder = IncidentRecorder(path, cfg.id)
    svc = IncidentService(session, cfg, ServiceSettings(), recorder=recorder).start()
    live = FoxgloveLive(session, cfg, port=0)
    cl = client(endpoint)
    statuses: list = []
    status_sub = cl.declare_subscriber(wire.key(cfg.id, FALLEN, "status"),
                                       lambda s: statuses.append(wire.decode(s.payload.to_bytes(), expect=wire.Status)))
    walks = {WALKER: walk(WALKER, seconds=60.0, seed=1), FALLEN: walk(FALLEN, seconds=60.0, seed=2, collapse_at=1015.0)}
    wearables = {rid: Wearable(cl, cfg.id, rid) for rid in walks}
    ws = FoxgloveClient(f"ws://127.0.0.1:{live.port}")
    sent = threading.Event()

    def send():  # at 10x real time, so poses still flow while the client subscribes
        for k in range(len(walks[WALKER].frames)):
            for rid, w in walks.items():
                wearables[rid].send("imu", w.frames[k])
            time.sleep(0.01)
        sent.set()

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    result: dict = {"cfg": cfg, "recording": path}
    try:
        result["ws_fix"] = ws.first_message(f"/responders/{WALKER}/live/location")
        result["ws_building"] = ws.first_message("/building", timeout=10.0)
        assert sent.wait(60)
        n = sum(len(w.frames) for w in walks.values())
        assert wait_until(lambda: svc.frames_processed >= n, 60)
        assert wait_until(lambda: any("man_down" in s.alarms for s in statuses), 15), "no man_down for the fallen walker"
        ack = wire.OperatorAction(action="ack", operator="alice", utc=time.time(), responder=FALLEN, alarm="man_down")
        cl.put(wire.key(cfg.id, "console", "op"), wire.encode(ack))
        assert wait_until(lambda: svc.received.get("op", 0) >= 1, 10)
        svc.wait_idle(10)
        result["bridge_poses"] = live.poses
    finally:
        ws.close()
        status_sub.undeclare()
        for w in wearables.values():
            w.close()
        live.close()
        svc.close()
        recorder.close()
        cl.close()
        session.close()
    return result


def test_the_live_server_sends_a_walking_responders_location_fix_with_its_covariance(incident_run):
    channel, log_time, payload = incident_run["ws_fix"]
    assert channel["encoding"] == "protobuf" and channel["schemaName"] == "foxglove.LocationFix"
    cls = message_class("foxglove.LocationFix", base64.b64decode(channel["schema"]))
    fix = decode_strictly(cls, payload)
    cfg = incident_run["cfg"]
    x, y, _ = cfg.to_enu(fix.latitude, fix.longitude)
    assert math.hypot(x, y) < 200.0  # the simulated walkers stay within 40 m of the origin
    assert fix.position_covariance_type == 3  # KNOWN
    cov = np.array(fix.position_covariance).reshape(3, 3)
    assert cov[0, 0] > 0 and cov[1, 1] > 0 and cov[0, 1] == cov[1, 0] and cov[2, 2] > 0
    assert abs(log_time / 1e9 - time.time()) < 3600  # a real UTC time, not the device clock
    scene = incident_run["ws_building"]
    assert scene[0]["schemaName"] == "foxglove.SceneUpdate"
    names = {e.id for e in decode_strictly(message_class("foxglove.SceneUpdate", base64.b64decode(scene[0]["schema"])),
                                           scene[2]).entities}
    assert {f"checkpoint/{cp.name}" for cp in cfg.checkpoints} <= names
    assert incident_run["bridge_poses"] > 20


@pytest.fixture(scope="module")
def exported(incident_run, tmp_path_factory):
    """``firetrack reprocess REC --export DIR`` of the live incident: DIR."""
    from typer.testing import CliRunner

    from client.cli import app

    folder = tmp_path_factory.mktemp("export")
    r = CliRunner().invoke(app, ["reprocess", str(incident_run["recording"]), "--export", str(folder)])
    assert r.exit_code == 0, r.output
    return folder


def test_the_exported_mcap_has_a_foxglove_schema_on_every_channel_and_every_message_decodes_with_it(incident_run, exported):
    from mcap.reader import make_reader

    known = foxglove_schema_names()
    classes: dict[int, object] = {}
    counts: dict[str, int] = {}
    decoded: dict[str, list] = {}
    with open(exported / "foxglove.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        for ch in summary.channels.values():
            schema = summary.schemas.get(ch.schema_id)
            assert schema is not None, f"{ch.topic}: no schema"
            assert schema.name in known, f"{ch.topic}: {schema.name} is not a Foxglove schema"
            assert schema.encoding == "protobuf" and ch.message_encoding == "protobuf", ch.topic
            classes[ch.id] = message_class(schema.name, schema.data)
        for schema, ch, msg in reader.iter_messages():
            m = decode_strictly(classes[ch.id], msg.data)
            counts[ch.topic] = counts.get(ch.topic, 0) + 1
            decoded.setdefault(ch.topic, []).append(m)
    cfg = incident_run["cfg"]
    for rid in (WALKER, FALLEN):
        for kind in ("live", "smoothed"):
            assert counts.get(f"/responders/{rid}/{kind}/location", 0) > 20, (rid, kind, counts)
            assert counts.get(f"/responders/{rid}/{kind}/pose", 0) == counts[f"/responders/{rid}/{kind}/location"]
    live = decoded[f"/responders/{WALKER}/live/location"]
    assert all(m.position_covariance_type == 3 and m.position_covariance[0] > 0 for m in live)
    assert all(m.position_covariance_type == 0 for m in decoded[f"/responders/{WALKER}/smoothed/location"])
    pose = decoded[f"/responders/{WALKER}/live/pose"][-1]
    assert pose.frame_id == f"{cfg.id}/enu"
    assert abs(pose.pose.orientation.w ** 2 + pose.pose.orientation.z ** 2 - 1.0) < 1e-9
    tf = decoded["/tf"][0]
    assert {t.child_frame_id for t in tf.transforms} == {f"{cfg.id}/floor_{f.number}" for f in cfg.floors}
    if cfg.floor_plan(-1).available:  # the museum's plan of floor -1, from ../shared/data (the others fall back to it)
        for f in cfg.floors:
            grid = decoded[f"/building/plan/floor_{f.number}"][0]
            rows = len(grid.data) // grid.row_stride
            assert grid.column_count > 100 and rows > 50 and len(grid.data) == grid.row_stride * rows
            assert [fl.name for fl in grid.fields] == ["red", "green", "blue", "alpha"]
    alarms = [m.message for m in decoded.get("/alarms", [])]
    assert f"{FALLEN}: man_down" in alarms, alarms
    ops = [m.message for m in decoded.get("/operator", [])]
    assert any("alice" in m and "ack" in m and FALLEN in m for m in ops), ops


def _serve(args):
    from client.cli import app
    from service.protocol.session import free_local_port
    from typer.testing import CliRunner

    return CliRunner().invoke(app, ["serve", "--no-console", "--listen", f"tcp/127.0.0.1:{free_local_port()}",
                                    "--seconds", "0.5", *args])


def test_serve_foxglove_prints_where_to_connect():
    r = _serve(["--foxglove", "0"])
    assert r.exit_code == 0, r.output
    assert "foxglove: ws://127.0.0.1:" in r.output


def test_serve_foxglove_without_the_package_names_the_extra(monkeypatch):
    import sys

    for name in ("foxglove", "foxglove.messages", "foxglove.channels"):  # as if foxglove-sdk were not installed
        monkeypatch.setitem(sys.modules, name, None)
    for name in ("service.shell.foxglove_live", "service.review.foxglove_scene"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    r = _serve(["--foxglove", "0"])
    assert r.exit_code == 1
    assert "pip install 'firetrack[foxglove]'" in r.output


def test_the_same_export_writes_a_kml_track_per_responder_and_kind(exported):
    import xml.etree.ElementTree as ET

    from service.review.kml import GX_NS, KML_NS

    ns = {"k": KML_NS, "gx": GX_NS}
    root = ET.parse(exported / "tracks.kml").getroot()
    tracks = {p.find("k:name", ns).text: p.find("gx:Track", ns) for p in root.findall(".//k:Placemark", ns)}
    assert set(tracks) == {f"{rid} {kind}" for rid in (WALKER, FALLEN) for kind in ("live", "smoothed")}
    for name, tr in tracks.items():
        when = [np.datetime64(w.text.rstrip("Z")) for w in tr.findall("k:when", ns)]
        assert len(when) == len(tr.findall("gx:coord", ns)) > 20, name
        assert all(b > a for a, b in zip(when, when[1:])), name
        assert abs((when[0] - np.datetime64(int(time.time() * 1000), "ms")) / np.timedelta64(1, "s")) < 3600


def test_a_plan_grid_puts_each_pixel_where_the_plans_georeference_does(tmp_path):
    from PIL import Image

    from service.protocol.floorplan import plan_pixel_to_enu
    from service.protocol.incident import incident_from_dict
    from service.review.foxglove_scene import plan_grids

    img = np.zeros((30, 40, 4), dtype=np.uint8)  # 40 x 30 pixels, all transparent but one 4 x 4 block
    img[4:8, 28:32] = (255, 0, 0, 255)  # rows (v) 4-7, columns (u) 28-31
    Image.fromarray(img, "RGBA").save(tmp_path / "plan.png")
    cfg = incident_from_dict({"origin": {"lat": 49.46, "lon": 11.11}, "floor_plans": [{
        "floor": 0, "image": "plan.png",
        "georeference": {"centre_lat": 49.4601, "centre_lon": 11.1102, "rotation_deg": -30.0, "metres_per_pixel": 0.5}}]},
        base_dir=tmp_path)
    made = plan_grids(cfg, 0.0, cell_m=2.0)[0]  # 4 x 4 pixels a cell
    grid = decode_strictly(message_class("foxglove.Grid", made.get_schema().data), made.encode())
    assert grid.column_count == 10 and abs(grid.cell_size.x - 2.0) < 1e-9
    cells = np.frombuffer(grid.data, dtype=np.uint8).reshape(-1, grid.column_count, 4)
    (row, col), = np.argwhere(cells[:, :, 0] == 255)
    q = grid.pose.orientation
    yaw = 2 * math.atan2(q.z, q.w)
    cx, cy = (col + 0.5) * grid.cell_size.x, (row + 0.5) * grid.cell_size.y  # the cell's centre in the grid's frame
    x = grid.pose.position.x + math.cos(yaw) * cx - math.sin(yaw) * cy
    y = grid.pose.position.y + math.sin(yaw) * cx + math.cos(yaw) * cy
    ex, ey = plan_pixel_to_enu(cfg.floor_plan(0), 30.0, 6.0)  # the block's centre in pixels
    assert math.hypot(x - ex, y - ey) < 1e-6

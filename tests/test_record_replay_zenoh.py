"""Record an incident from a real zenoh router on loopback, then replay it into the router."""
from __future__ import annotations

import threading
import time

import msgpack
import pytest
import typer
import zenoh
from typer.testing import CliRunner

from service.cli.record import record, record_command, replay, replay_command
from service.protocol.session import client_config, free_local_port, router_config
from service.review.recorder import IncidentRecorder, read_recording

TIMEOUT_S = 10.0


@pytest.fixture
def router():
    """An in-process zenoh router on a free loopback port, no multicast scouting."""
    port = free_local_port()
    session = zenoh.open(router_config([f"tcp/127.0.0.1:{port}"]))
    try:
        yield f"tcp/127.0.0.1:{port}"
    finally:
        session.close()


@pytest.fixture
def client(router):
    sessions = []

    def make():
        sessions.append(zenoh.open(client_config(router)))
        return sessions[-1]

    yield make
    for s in sessions:
        s.close()


def _wait(predicate, what: str, timeout: float = TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


class _Collector:
    def __init__(self, session, key_expr: str):
        self.samples: list[tuple[str, bytes, float]] = []
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(key_expr, self._on)

    def _on(self, sample):
        with self.lock:
            self.samples.append((str(sample.key_expr), sample.payload.to_bytes(), time.monotonic()))

    def __len__(self):
        with self.lock:
            return len(self.samples)


def _traffic(incident: str):
    """What a live incident looks like: IMU batches, fixes, and the service's poses and status."""
    msgs = []
    for i in range(60):
        responder = f"ff{i % 2}"
        kind = ("imu", "imu", "imu", "fix", "pose", "status")[i % 6]
        body = {"seq": i, "t": 10.0 + 0.01 * i, "acc": [[0.1 * i, 0.0, 9.81]] * (i % 5 + 1)}
        msgs.append((f"firetrack/{incident}/{responder}/{kind}", msgpack.packb(body)))
    return msgs


def test_record_then_replay_inputs(router, client, tmp_path):
    path = tmp_path / "incident.mcap"
    traffic = _traffic("t1")
    ready, stop = threading.Event(), threading.Event()
    result: dict = {}

    def run():
        result["summary"] = record(router, "t1", path, duration=TIMEOUT_S, stop_event=stop, ready=ready,
                                   max_messages=len(traffic), flush_interval_s=0.1, quiet=True)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    assert ready.wait(TIMEOUT_S), "the recorder never subscribed"
    pub_session = client()
    publishers = {k: pub_session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
                  for k in [*dict.fromkeys(k for k, _ in traffic), "firetrack/t1/ff0/imu/raw"]}
    _wait(lambda: all(p.matching_status.matching for p in publishers.values()), "the recorder's subscription to reach the publisher")
    pub_session.put("firetrack/other/ff0/imu", b"another incident: not subscribed")
    publishers["firetrack/t1/ff0/imu/raw"].put(b"not a firetrack/{incident}/{responder}/{kind} key")
    for key, payload in traffic:
        publishers[key].put(payload)
    thread.join(TIMEOUT_S)
    stop.set()
    thread.join(2.0)
    assert not thread.is_alive()
    assert result["summary"]["messages"] == len(traffic) and result["summary"]["rejected"] == {"firetrack/t1/ff0/imu/raw": 1}

    back = list(read_recording(path))
    assert [(m.key, m.payload) for m in back] == traffic
    assert all(m.publish_time is not None for m in back)  # the router stamps samples
    assert all(abs(m.receive_time - time.time()) < 60 for m in back)

    # replay the inputs as fast as possible into the router
    listener = _Collector(client(), "firetrack/t1/**")
    report = replay(path, router, speed=0, quiet=True)
    inputs = [(k, p) for k, p in traffic if k.rsplit("/", 1)[1] in ("imu", "fix")]
    assert report["messages"] == len(inputs) and report["unheard_keys"] == []
    _wait(lambda: len(listener) >= len(inputs), "the replayed inputs")
    time.sleep(0.2)  # anything extra (pose, status) would arrive by now
    assert [(k, p) for k, p, _ in listener.samples] == inputs

    # all kinds, one responder, under another incident name
    renamed = _Collector(client(), "firetrack/t1-replay/**")
    replay(path, router, speed=0, kinds=None, responders=["ff1"], incident="t1-replay", quiet=True)
    want = [(k.replace("/t1/", "/t1-replay/"), p) for k, p in traffic if "/ff1/" in k]
    _wait(lambda: len(renamed) >= len(want), "the renamed replay")
    assert [(k, p) for k, p, _ in renamed.samples] == want

    # an incident nobody listens to: the messages went nowhere, and the report says which keys
    report = replay(path, router, speed=0, responders=["ff1"], incident="nobody-here", quiet=True,
                    wait_for_subscribers_s=0.2)
    assert report["messages"] > 0
    assert report["unheard_keys"] and all(k.startswith("firetrack/nobody-here/ff1/") for k in report["unheard_keys"])


def test_replay_keeps_the_recorded_timing(router, client, tmp_path):
    path = tmp_path / "timed.mcap"
    with IncidentRecorder(path, "t2") as rec:
        for i in range(11):  # one fix every 0.1 s for 1 s, plus poses that must not be replayed
            rec.write("firetrack/t2/ff0/fix", msgpack.packb({"i": i}), 1000.0 + 0.1 * i)
            rec.write("firetrack/t2/ff0/pose", b"\x00", 1000.0 + 0.1 * i + 0.05)
    listener = _Collector(client(), "firetrack/t2/**")
    report = replay(path, router, speed=2.0, start=0.2, quiet=True)  # 0.8 s of recording -> 0.4 s
    assert report["messages"] == 9
    _wait(lambda: len(listener) >= 9, "the timed replay")
    arrivals = [t for _, _, t in listener.samples]
    assert [msgpack.unpackb(p)["i"] for _, p, _ in listener.samples] == list(range(2, 11))
    assert 0.35 < arrivals[-1] - arrivals[0] < 1.0
    assert 0.35 < report["seconds"] < 1.0


def test_commands_report_errors_clearly(router, tmp_path):
    app = typer.Typer()
    app.command("record")(record_command)
    app.command("replay")(replay_command)
    runner = CliRunner()
    closed = f"tcp/127.0.0.1:{free_local_port()}"
    (tmp_path / "x.mcap").write_bytes(b"")
    res = runner.invoke(app, ["record", "--connect", closed, "--incident", "demo", "--out", str(tmp_path / "y.mcap"), "--seconds", "1"])
    assert res.exit_code == 1 and "cannot reach a zenoh router" in res.output
    res = runner.invoke(app, ["record", "--connect", router, "--incident", "demo", "--out", str(tmp_path / "x.mcap"), "--seconds", "0.1"])
    assert res.exit_code == 1 and "already exists" in res.output
    res = runner.invoke(app, ["replay", str(tmp_path / "missing.mcap"), "--connect", router])
    assert res.exit_code == 1 and "missing.mcap" in res.output
    path = tmp_path / "z.mcap"
    with IncidentRecorder(path, "demo") as rec:
        rec.write("firetrack/demo/ff0/pose", b"\x00", 1.0)
    res = runner.invoke(app, ["replay", str(path), "--connect", router, "--speed", "0"])
    assert res.exit_code == 1 and "no messages of kinds" in res.output and "pose" in res.output
    res = runner.invoke(app, ["record", "--connect", router, "--incident", "demo", "--out", str(tmp_path / "w.mcap"), "--seconds", "0.2"])
    assert res.exit_code == 0, res.output
    assert read_recording(tmp_path / "w.mcap") is not None


def test_record_keeps_every_sample_of_a_burst(router, client, tmp_path):
    """Faster than the writer's batch: nothing may be dropped between the queue and the file."""
    path, n = tmp_path / "burst.mcap", 5000
    ready, result = threading.Event(), {}
    thread = threading.Thread(target=lambda: result.update(
        record(router, "t3", path, duration=TIMEOUT_S, ready=ready, max_messages=n, quiet=True)), daemon=True)
    thread.start()
    assert ready.wait(TIMEOUT_S)
    pub = client().declare_publisher("firetrack/t3/ff0/imu", congestion_control=zenoh.CongestionControl.BLOCK)
    _wait(lambda: pub.matching_status.matching, "the recorder's subscription")
    for i in range(n):
        pub.put(i.to_bytes(4, "little"))
    thread.join(TIMEOUT_S)
    assert not thread.is_alive() and result["messages"] == n
    assert [int.from_bytes(m.payload, "little") for m in read_recording(path)] == list(range(n))


def test_replay_stops_on_request(router, client, tmp_path):
    path = tmp_path / "long.mcap"
    with IncidentRecorder(path, "t4") as rec:
        for i in range(101):  # 10 s of fixes at 10 Hz
            rec.write("firetrack/t4/ff0/fix", bytes([i]), 1000.0 + 0.1 * i)
    listener = _Collector(client(), "firetrack/t4/**")
    stop = threading.Event()
    threading.Timer(0.5, stop.set).start()
    began = time.monotonic()
    report = replay(path, router, speed=1.0, stop_event=stop, quiet=True)
    assert report["stopped"] and time.monotonic() - began < 2.0
    assert 2 <= report["messages"] < 20
    _wait(lambda: len(listener) >= report["messages"], "the messages sent before the stop")
    assert [p for _, p, _ in listener.samples] == [bytes([i]) for i in range(report["messages"])]

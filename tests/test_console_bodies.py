"""The console's operator endpoints answer every malformed body with a 4xx, never a 500
(issue 20: a 30 k-deep JSON body raised RecursionError)."""
from __future__ import annotations

import http.client
import json
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from client.console.server import POST_MAX_BYTES, start_console
from service.protocol import wire
from service.protocol.incident import default_incident
from tests.zenoh_util import client, router, wait_until


@pytest.fixture(scope="module")
def console():
    session, endpoint = router()
    cfg = default_incident()
    handle = start_console(session, cfg, port=0)
    cl = client(endpoint)
    cl.put(wire.key(cfg.id, "foxtrot", "status"), wire.encode(wire.Status(
        responder="foxtrot", t=77.5, motion="still", motion_since=70.0, last_heard=time.time())))
    assert wait_until(lambda: handle.board.device_time("foxtrot") == 77.5, 5)
    yield handle
    cl.close()
    handle.close()
    session.close()


def post(console, path: str, body: bytes, content_type: str | None = "application/json") -> tuple[int, dict]:
    conn = http.client.HTTPConnection("127.0.0.1", console.port, timeout=10)
    headers = {"Content-Type": content_type} if content_type else {}
    conn.request("POST", path, body=body, headers=headers)
    res = conn.getresponse()
    data = res.read()
    conn.close()
    try:
        return res.status, json.loads(data)
    except ValueError:
        return res.status, {"raw": data[:200]}


DEPTH = 30_000
MALFORMED = {
    "a list 30 k deep": b"[" * DEPTH + b"]" * DEPTH,
    "a map 30 k deep": b'{"a":' * DEPTH + b"1" + b"}" * DEPTH,
    "unclosed nesting": b"[" * DEPTH,
    "not UTF-8": b'{"responder": "\xff\xfe"}',
    "NaN": b'{"responder": "foxtrot", "x": NaN, "y": 1, "floor": 0}',
    "Infinity": b'{"responder": "foxtrot", "x": 1, "y": -Infinity, "floor": 0}',
    "an integer beyond any float": b'{"responder": "foxtrot", "x": 1' + b"0" * 400 + b', "y": 1, "floor": 0}',
    "an integer of 5000 digits": b'{"responder": "foxtrot", "x": ' + b"9" * 5000 + b', "y": 1, "floor": 0}',
    "a float overflow": b'{"responder": "foxtrot", "x": 1e999, "y": 1, "floor": 0}',
    "empty": b"",
    "whitespace": b"   \n ",
    "a list": b"[1, 2, 3]",
    "a string": b'"fix me"',
    "null": b"null",
    "truncated": b'{"responder": "foxtrot", "x": 1',
    "a lone surrogate": b'{"responder": "\\ud800", "x": 1, "y": 1, "floor": 0}',
    "a BOM": b'\xef\xbb\xbf{"responder": "foxtrot"}',
    "a duplicate key": b'{"responder": "foxtrot", "responder": ["x"], "x": 1, "y": 1}',
    "responder as a map": b'{"responder": {"a": 1}, "x": 1, "y": 1, "floor": 0}',
    "floor as a float": b'{"responder": "foxtrot", "x": 1, "y": 1, "floor": 0.5}',
    "floor beyond any floor": b'{"responder": "foxtrot", "x": 1, "y": 1, "floor": ' + b"9" * 100 + b"}",
    "sigma as text": b'{"responder": "foxtrot", "x": 1, "y": 1, "floor": 0, "sigma": "wide"}',
    "sigma negative": b'{"responder": "foxtrot", "x": 1, "y": 1, "floor": 0, "sigma": -3}',
    "name as a list": b'{"responder": "foxtrot", "name": ["door"]}',
    "name and x": b'{"responder": "foxtrot", "name": "t01-lm2", "x": 1}',
    "a 10 k-character responder": b'{"responder": "' + b"r" * 10_000 + b'", "x": 1, "y": 1}',
}


@pytest.mark.parametrize("path", ["/api/fix", "/api/checkpoint"])
@pytest.mark.parametrize("what", list(MALFORMED))
def test_every_malformed_body_is_a_4xx_with_a_reason(console, path, what):
    status, body = post(console, path, MALFORMED[what])
    assert 400 <= status < 500, (what, status, body)
    assert isinstance(body.get("error"), str) and body["error"]


def test_the_size_limit_and_the_content_type_are_4xx_too(console):
    status, body = post(console, "/api/fix", b'{"x": "' + b"a" * (POST_MAX_BYTES + 10) + b'"}')
    assert status == 413
    assert post(console, "/api/fix", b"{}", content_type=None)[0] == 415
    assert post(console, "/api/checkpoint", b"{}", content_type="text/json")[0] == 415


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12)
FIELDS = ("responder", "x", "y", "floor", "sigma", "name", "sigma_m", "note")


@settings(max_examples=150)
@given(st.dictionaries(st.sampled_from(FIELDS), json_values | st.just("foxtrot"), max_size=6),
       st.sampled_from(["/api/fix", "/api/checkpoint"]))
def test_any_json_object_gets_an_answer_below_500(console, body, path):
    status, answer = post(console, path, json.dumps(body).encode())
    assert status < 500, (body, status, answer)
    if status >= 400:
        assert answer.get("error")


def test_a_fix_outside_the_incidents_extent_is_refused_with_a_clear_message(console):
    """Issue 32, attack 7: an operator's slip, x = 12,345,678, was taken (200) and stopped a track."""
    status, body = post(console, "/api/fix", json.dumps({"responder": "foxtrot", "x": 12_345_678, "y": 2.0,
                                                         "floor": 0}).encode())
    assert status == 422 and "outside its extent" in body["error"] and "12,345,678 m from the incident's origin" in body["error"]
    ok, _ = post(console, "/api/fix", json.dumps({"responder": "foxtrot", "x": 10.0, "y": 2.0, "floor": 0}).encode())
    assert ok == 200


def test_the_service_refuses_an_operators_fix_outside_the_extent_and_audits_it():
    """A fix that reaches the service by another way than this console (another console, a
    script with an operator's certificate) is held to the same extent."""
    from service.core.incident_core import Inbound, IncidentCore
    from tests.walkers import walk

    cfg = default_incident()
    core = IncidentCore(cfg)
    w = walk("ff1", seconds=3.0)
    for k, f in enumerate(w.frames):
        core.feed(Inbound("imu", wire.key(cfg.id, "ff1", "imu"), wire.encode(f), 100.0 + 0.1 * k))
    audits = []
    for x in (12_345_678.0, 10.0):
        fix = wire.Fix.checkpoint("ff1", float(w.frames[-1].t[-1]), x=x, y=2.0, floor=0, operator="o")
        op = wire.OperatorAction(action="fix", operator="o", utc=time.time(), responder="ff1", fix=wire.encode(fix))
        out = core.feed(Inbound("op", wire.key(cfg.id, "console", "op"), wire.encode(op), 104.0))
        audits += [o.message for o in out if isinstance(o.message, wire.Audit)]
    assert [(a.outcome, a.reason) for a in audits] == [("refused", "outside_extent"), ("accepted", None)]
    assert "outside the incident's extent" in audits[0].detail

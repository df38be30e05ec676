"""The wire schema and codec (service.protocol.wire): round trips, byte layout, every reject reason, fuzz."""
from __future__ import annotations

import json
import math
import struct

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from pydantic import ValidationError
from typer.testing import CliRunner

from service.protocol import wire
from service.protocol.wire import (
    MAX_SAMPLES,
    REJECT_REASONS,
    SCHEMA_VERSION,
    Fix,
    ImuBatch,
    Pose,
    Status,
    WireError,
    decode,
    encode,
    imu_batches_from_arrays,
    json_schema,
    key,
    key_all,
    parse_key,
)

# Frames with values beyond 1e154 are meant here: the fast decoder's finiteness check (a dot
# product) overflows to inf on them, numpy says so once, and the slow path decides, as designed.
pytestmark = pytest.mark.filterwarnings("ignore:overflow encountered in matmul:RuntimeWarning")

# --------------------------------------------------------------------------------------
# Strategies
# --------------------------------------------------------------------------------------
ids = st.from_regex(r"[A-Za-z0-9_.-]{1,64}", fullmatch=True)
finite = st.floats(allow_nan=False, allow_infinity=False)
moderate = st.floats(-1e6, 1e6, allow_nan=False)
texts = st.text(max_size=20)


@st.composite
def sample_times(draw, n):
    rate = draw(st.floats(6.0, 1700.0))  # with the 10 % jitter below: 5.5 .. 1890 Hz
    t0 = draw(st.floats(-1e5, 1e5))
    jitter = draw(hnp.arrays(np.float64, n, elements=st.floats(0.9, 1.1)))
    t = t0 + np.concatenate([[0.0], np.cumsum(jitter[1:] / rate)])
    return t


@st.composite
def imu_batches(draw):
    n = draw(st.integers(1, 40))
    t = draw(sample_times(n))
    vec = hnp.arrays(np.float64, (n, 3), elements=finite)
    kw = {}
    if draw(st.booleans()):
        kw["mag"] = draw(vec)
    m = draw(st.integers(0, 5))
    if m:
        pt = np.sort(draw(hnp.arrays(np.float64, m, elements=st.floats(-1e5, 1e5), unique=True)))
        kw["pressure_t"], kw["pressure"] = pt, draw(hnp.arrays(np.float64, m, elements=st.floats(300, 1100)))
    return ImuBatch(responder=draw(ids), device=draw(st.text(min_size=1, max_size=30)), seq=draw(st.integers(0, 2**63)),
                    t=t, acc=draw(vec), gyr=draw(vec), carry=draw(st.sampled_from(wire.CARRY_POSITIONS)), **kw)


@st.composite
def fixes(draw):
    source = draw(st.sampled_from(["checkpoint", "gnss", "uwb"]))
    common = dict(responder=draw(ids), t=draw(finite), operator=draw(st.none() | texts))
    if source == "checkpoint":
        named = draw(st.booleans())
        at = {} if named and draw(st.booleans()) else {"x": draw(moderate), "y": draw(moderate)}
        return Fix.checkpoint(**common, name=draw(st.text(min_size=1, max_size=20)) if named else None,
                              floor=draw(st.none() | st.integers(-5, 50)), sigma=draw(st.none() | st.floats(0.01, 10)), **at)
    if source == "gnss":
        return Fix.gnss(**common, lat=draw(st.floats(-90, 90)), lon=draw(st.floats(-180, 180)), accuracy=draw(st.floats(0.1, 1e3)))
    return Fix.uwb(**common, anchor=draw(st.text(min_size=1, max_size=10)), range=draw(st.floats(0, 1e3)),
                   sigma=draw(st.floats(0.001, 10)))


@st.composite
def poses(draw):
    a, c = draw(st.floats(0, 1e4)), draw(st.floats(0, 1e4))
    b = draw(st.floats(-1e4, 1e4))
    return Pose(responder=draw(ids), t=draw(finite), x=draw(moderate), y=draw(moderate), floor=draw(st.integers(-10, 100)),
                lat=draw(st.floats(-90, 90)), lon=draw(st.floats(-180, 180)),
                heading_deg=draw(st.floats(0, 360, exclude_max=True)), cov=[[a, b], [b, c]],
                steps=draw(st.integers(0, 10**9)), source=draw(st.sampled_from(["pdr", "fused"])),
                seq=draw(st.integers(0, 2**40)), published_at=draw(st.floats(0, 2e9)))


@st.composite
def statuses(draw):
    return Status(responder=draw(ids), t=draw(finite), motion=draw(st.sampled_from(["walking", "still", "no_motion"])),
                  motion_since=draw(finite), alarms=draw(st.lists(st.sampled_from(["man_down", "lost_contact",
                                                                                   "rejected_frames"]), max_size=3)),
                  rejected=draw(st.dictionaries(st.sampled_from(REJECT_REASONS + ("duplicate", "late")),
                                                st.integers(0, 10**6))),
                  frames=draw(st.integers(0, 10**9)), gaps=draw(st.integers(0, 10**6)), last_heard=draw(st.floats(0, 2e9)),
                  steps=draw(st.integers(0, 10**7)))


messages = st.one_of(imu_batches(), fixes(), poses(), statuses())


def imu(n=10, rate=100.0, t0=100.0, **kw) -> ImuBatch:
    rng = np.random.default_rng(n)
    t = t0 + np.arange(n) / rate
    args = dict(responder="ff1", device="phone-A", seq=7, t=t, acc=rng.normal(size=(n, 3)), gyr=rng.normal(size=(n, 3)))
    args.update(kw)
    return ImuBatch(**args)


def wire_map(msg) -> dict:
    """The plain msgpack map of a message, to be spoiled by a test."""
    return msgpack.unpackb(encode(msg))


def reject(data, **kw) -> WireError:
    payload = data if isinstance(data, bytes) else msgpack.packb(data)
    with pytest.raises(WireError) as e:
        decode(payload, **kw)
    return e.value


# --------------------------------------------------------------------------------------
# Round trips and layout
# --------------------------------------------------------------------------------------
@settings(max_examples=150, suppress_health_check=[HealthCheck.too_slow])
@given(messages)
def test_every_message_round_trips(msg):
    back = decode(encode(msg))
    assert type(back) is type(msg)
    assert back == msg
    assert decode(encode(msg), expect=type(msg)) == msg


def test_arrays_come_back_as_read_only_float64_of_the_right_shape():
    b = decode(encode(imu(n=12, mag=np.ones((12, 3)), pressure_t=[100.01, 100.05], pressure=[976.0, 976.1])))
    assert b.t.shape == (12,) and b.acc.shape == b.gyr.shape == b.mag.shape == (12, 3)
    assert b.pressure.shape == b.pressure_t.shape == (2,)
    assert all(a.dtype == np.float64 and not a.flags.writeable for a in (b.t, b.acc, b.gyr, b.mag))
    p = decode(encode(Pose(responder="r", t=1, x=0, y=0, floor=0, lat=49, lon=11, heading_deg=0, cov=np.eye(2) * 4,
                           steps=0, source="pdr", seq=0, published_at=0)))
    assert p.cov.shape == (2, 2) and p.cov[0, 0] == 4


def test_building_a_message_does_not_freeze_the_callers_array():
    acc = np.zeros((3, 3))
    b = imu(n=3, acc=acc)
    acc[0, 0] = 1.0  # still writable for its owner
    assert not b.acc.flags.writeable


def test_byte_layout_is_readable_with_plain_msgpack_and_struct():
    acc = np.arange(30, dtype=np.float64).reshape(10, 3) * 0.5
    b = imu(acc=acc, mag=acc + 100)
    d = msgpack.unpackb(encode(b))  # no numpy below this line
    assert d["v"] == SCHEMA_VERSION and d["kind"] == "imu"
    assert d["responder"] == "ff1" and d["seq"] == 7 and d["carry"] == "unknown"
    assert isinstance(d["t"], bytes) and len(d["t"]) == 8 * 10
    assert isinstance(d["acc"], bytes) and len(d["acc"]) == 8 * 10 * 3 and len(d["mag"]) == 8 * 30
    assert struct.unpack("<3d", d["acc"][:24]) == (0.0, 0.5, 1.0)  # row 0: x, y, z
    assert struct.unpack("<3d", d["acc"][24:48]) == (1.5, 2.0, 2.5)  # row-major
    assert struct.unpack("<d", d["t"][8:16])[0] == pytest.approx(100.01)
    assert "pressure" not in d and "pressure_t" not in d  # None is left out


def test_pose_cov_is_four_floats_row_major():
    cov = np.array([[2.0, 0.5], [0.5, 3.0]])
    d = wire_map(Pose(responder="r", t=1, x=0, y=0, floor=0, lat=49, lon=11, heading_deg=10, cov=cov, steps=0,
                      source="fused", seq=0, published_at=0))
    assert struct.unpack("<4d", d["cov"]) == (2.0, 0.5, 0.5, 3.0)


def test_unknown_keys_are_ignored_and_absent_equals_nil():
    d = wire_map(Fix.gnss("ff1", 3.0, lat=49.0, lon=11.0, accuracy=4.0))
    d["future_field"] = [1, 2]
    d["operator"] = None
    assert decode(msgpack.packb(d)) == Fix.gnss("ff1", 3.0, lat=49.0, lon=11.0, accuracy=4.0)


# --------------------------------------------------------------------------------------
# Every reject reason, each with a detail that says what and where
# --------------------------------------------------------------------------------------
def test_oversize_is_checked_first():
    e = reject(b"\xc1" * 100, max_bytes=50)
    assert e.reason == "oversize" and "100 bytes" in e.detail and "50" in e.detail
    big = encode(imu(n=4000))
    assert reject(big, max_bytes=len(big) - 1).reason == "oversize"
    assert decode(big, max_bytes=len(big)) == imu(n=4000)


@pytest.mark.parametrize("payload", [b"", b"\xc1", encode(imu())[:-5], encode(imu()) + b"\x00", b"\x92\x01"])
def test_invalid_msgpack(payload):
    e = reject(payload)
    assert e.reason == "msgpack" and e.detail


def test_invalid_utf8_is_msgpack():
    assert reject(b"\x81\xa1v\xa2\xff\xfe").reason == "msgpack"


def test_not_a_map():
    for value in ([1, 2], 3, "imu", None):
        e = reject(value)
        assert e.reason == "not_a_map" and type(value).__name__ in e.detail


@pytest.mark.parametrize("v, words", [(2, "newer"), (SCHEMA_VERSION + 7, "newer"), (0, "does not exist"),
                                      ("1", "integer"), (1.0, "integer"), (True, "integer"), (None, "integer")])
def test_version(v, words):
    d = wire_map(imu())
    d["v"] = v
    e = reject(d)
    assert e.reason == "version" and words in e.detail


def test_missing_version():
    d = wire_map(imu())
    del d["v"]
    assert reject(d).detail == "no 'v' field"


def test_kind():
    d = wire_map(imu())
    d["kind"] = "teleport"
    e = reject(d)
    assert e.reason == "kind" and "teleport" in e.detail and "imu" in e.detail
    del d["kind"]
    assert reject(d).reason == "kind"
    e = reject(encode(imu()), expect=Pose)
    assert e.reason == "kind" and "expected pose, got imu" in e.detail


@pytest.mark.parametrize("change, where", [
    ({"seq": -1}, "seq"), ({"seq": "3"}, "seq"), ({"seq": 1.0}, "seq"), ({"responder": "ff/1"}, "responder"),
    ({"responder": ""}, "responder"), ({"carry": "helmet"}, "carry"), ({"device": 5}, "device"),
    ({"t": [100.0, 100.01]}, "t"), ({"acc": None}, "acc"),
])
def test_schema_errors_name_the_field(change, where):
    d = wire_map(imu())
    d.update(change)
    e = reject(d)
    assert e.reason == "schema" and e.detail.startswith("imu: ") and f" {where}:" in f" {e.detail[5:]}"


def test_arrays_as_lists_are_refused_with_a_reason():
    d = wire_map(imu(n=2))
    d["t"] = [100.0, 100.01]
    assert "msgpack bin" in reject(d).detail


def test_missing_field_is_schema():
    d = wire_map(imu())
    del d["gyr"]
    e = reject(d)
    assert e.reason == "schema" and "gyr" in e.detail and "required" in e.detail.lower()


@pytest.mark.parametrize("fix, words", [
    ({"source": "gnss", "lat": 49.0, "lon": 11.0}, "accuracy: Field required"),
    ({"source": "uwb", "anchor": "A1", "range": 2.0}, "sigma: Field required"),
    ({"source": "checkpoint"}, "a checkpoint name or x and y"),
    ({"source": "checkpoint", "x": 1.0}, "x and y together"),
    ({"source": "gnss", "lat": 49.0, "lon": 11.0, "accuracy": 3.0, "anchor": "A1"}, "anchor: not part of a gnss fix"),
    ({"source": "checkpoint", "name": "door", "range": 1.0}, "range: not part of a checkpoint fix"),
    ({"source": "gnss", "lat": 91.0, "lon": 11.0, "accuracy": 3.0}, "lat"),
    ({"source": "gnss", "lat": 49.0, "lon": 11.0, "accuracy": 0.0}, "accuracy"),
    ({"source": "uwb", "anchor": "A1", "range": -1.0, "sigma": 0.1}, "range"),
    ({"source": "radar", "name": "x"}, "source"),
])
def test_fix_fields_per_source(fix, words):
    e = reject({"v": 1, "kind": "fix", "responder": "ff1", "t": 1.0, **fix})
    assert e.reason == "schema" and words in e.detail
    with pytest.raises(ValidationError):
        Fix(responder="ff1", t=1.0, **fix)


def test_pose_constraints():
    base = wire_map(Pose(responder="r", t=1, x=0, y=0, floor=0, lat=49, lon=11, heading_deg=0, cov=np.eye(2), steps=0,
                         source="pdr", seq=0, published_at=0))
    assert "heading_deg" in reject({**base, "heading_deg": 360.0}).detail
    asym = np.array([[1.0, 0.5], [0.4, 1.0]]).tobytes()
    assert "symmetric" in reject({**base, "cov": asym}).detail
    assert reject({**base, "cov": np.ones(3).tobytes()}).reason == "shape"
    assert reject({**base, "source": "magic"}).reason == "schema"


@pytest.mark.parametrize("field, data, words", [
    ("t", b"\x00" * 9, "9 bytes is not a whole number of float64"),
    ("acc", np.zeros(10 * 3 + 1).tobytes(), "not a whole number of row of 3 float64"),
    ("acc", np.zeros((9, 3)).tobytes(), "acc: 9 rows for 10 samples"),
    ("gyr", np.zeros((11, 3)).tobytes(), "gyr: 11 rows for 10 samples"),
    ("mag", np.zeros((3, 3)).tobytes(), "mag: 3 rows"),
    ("pressure", np.zeros(2).tobytes(), "pressure and pressure_t come together"),
])
def test_shape(field, data, words):
    d = wire_map(imu())
    d[field] = data
    e = reject(d)
    assert e.reason == "shape" and words in e.detail


def test_pressure_count_must_match_its_times():
    d = wire_map(imu(pressure_t=[100.0, 100.05], pressure=[976.0, 976.1]))
    d["pressure"] = np.zeros(3).tobytes()
    assert "pressure: 3 values for 2 times" in reject(d).detail


def test_sample_count_bounds():
    d = wire_map(imu())
    d.update(t=b"", acc=b"", gyr=b"")
    e = reject(d)
    assert e.reason == "shape" and "1..4096 samples, got 0" in e.detail
    n = MAX_SAMPLES + 1
    d.update(t=(np.arange(n) * 0.01).tobytes(), acc=np.zeros((n, 3)).tobytes(), gyr=np.zeros((n, 3)).tobytes())
    assert reject(d).reason == "shape"
    one = wire_map(imu(n=1))
    assert decode(msgpack.packb(one)).n == 1  # a single sample has no rate to judge


def test_schema_outranks_shape():
    d = wire_map(imu())
    d["t"] = b"\x00" * 9
    d["seq"] = -4
    e = reject(d)
    assert e.reason == "schema" and "seq" in e.detail and "t:" in e.detail  # both told, schema counted


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_in_arrays_names_the_sample(bad):
    acc = np.zeros((10, 3))
    acc[6, 2] = bad
    d = wire_map(imu())
    d["acc"] = acc.tobytes()
    e = reject(d)
    assert e.reason == "nonfinite" and "acc" in e.detail and "[6, 2]" in e.detail
    t = 100 + np.arange(10) * 0.01
    t[3] = bad
    d = wire_map(imu())
    d["t"] = t.tobytes()
    e = reject(d)
    assert e.reason == "nonfinite" and "t: " in e.detail and "[3]" in e.detail


def test_nonfinite_scalars():
    d = wire_map(Fix.gnss("ff1", 3.0, lat=49.0, lon=11.0, accuracy=4.0))
    d["t"] = math.nan
    e = reject(d)
    assert e.reason == "nonfinite" and "t" in e.detail
    d = wire_map(Pose(responder="r", t=1, x=0, y=0, floor=0, lat=49, lon=11, heading_deg=0, cov=np.eye(2), steps=0,
                      source="pdr", seq=0, published_at=0))
    d["x"] = math.inf
    assert reject(d).reason == "nonfinite"
    d = wire_map(imu())
    d["pressure_t"], d["pressure"] = np.array([100.0]).tobytes(), np.array([np.nan]).tobytes()
    assert reject(d).reason == "nonfinite"


def test_time_order_names_the_sample():
    t = 100 + np.arange(10) * 0.01
    t[5] = t[4]
    d = wire_map(imu())
    d["t"] = t.tobytes()
    e = reject(d)
    assert e.reason == "time_order" and "t[5]" in e.detail and "t[4]" in e.detail
    t = 100 + np.arange(10) * 0.01
    t[[2, 3]] = t[[3, 2]]
    d["t"] = t.tobytes()
    assert "t[3]" in reject(d).detail
    d = wire_map(imu(pressure_t=[100.0, 100.05], pressure=[976.0, 976.1]))
    d["pressure_t"] = np.array([100.05, 100.0]).tobytes()
    e = reject(d)
    assert e.reason == "time_order" and "pressure_t[1]" in e.detail


@pytest.mark.parametrize("rate", [1.0, 4.9, 2100.0, 1e5])
def test_rate_outside_bounds(rate):
    d = wire_map(imu(rate=100.0))
    d["t"] = (100 + np.arange(10) / rate).tobytes()
    e = reject(d)
    assert e.reason == "rate" and "Hz" in e.detail


@pytest.mark.parametrize("rate", [5.0, 5.1, 100.0, 1999.0, 2000.0])
def test_rate_inside_bounds(rate):
    assert decode(encode(imu(rate=rate, t0=0.0))).n == 10


def test_rate_uses_the_median_interval():
    t = 100 + np.arange(10) * 0.01
    t[9] = t[8] + 5.0  # one long pause: mean rate 1.8 Hz, median 100 Hz
    assert decode(encode(imu(t=t))).n == 10


def test_reject_reasons_are_the_documented_ones():
    assert REJECT_REASONS == ("oversize", "msgpack", "not_a_map", "version", "kind", "schema", "shape", "nonfinite",
                              "time_order", "rate")
    with pytest.raises(ValueError):
        WireError("bogus", "x")


def test_python_construction_enforces_the_same_invariants():
    with pytest.raises(ValidationError, match="nonfinite|nan"):
        imu(acc=np.full((10, 3), np.nan))
    with pytest.raises(ValidationError, match="expected shape"):
        imu(acc=np.zeros((10, 2)))
    with pytest.raises(ValidationError, match="time_order|strictly"):
        imu(t=np.zeros(10))
    b = imu(pressure_t=np.empty(0), pressure=np.empty(0))
    assert b.pressure is None and b.pressure_t is None  # one spelling of "no pressure"


def test_encode_refuses_non_messages():
    with pytest.raises(TypeError):
        encode({"v": 1})


# --------------------------------------------------------------------------------------
# Fuzz: decode raises WireError and nothing else
# --------------------------------------------------------------------------------------
def decode_only_wire_errors(payload: bytes) -> None:
    try:
        decode(payload)
    except WireError as e:
        assert e.reason in REJECT_REASONS


@settings(max_examples=400)
@given(st.binary(max_size=600))
def test_fuzz_random_bytes(payload):
    decode_only_wire_errors(payload)


VALID = [encode(imu(n=5, mag=np.ones((5, 3)), pressure_t=[99.0], pressure=[970.0])),
         encode(Fix.checkpoint("ff1", 2.0, name="door", floor=1)), encode(Fix.uwb("ff1", 2.0, anchor="A", range=1, sigma=1)),
         encode(Pose(responder="r", t=1, x=0, y=0, floor=0, lat=49, lon=11, heading_deg=0, cov=np.eye(2), steps=0,
                     source="pdr", seq=0, published_at=0)),
         encode(Status(responder="r", t=1, motion="still", motion_since=0, last_heard=0, rejected={"rate": 1}))]


@settings(max_examples=400)
@given(st.sampled_from(VALID), st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=6),
       st.integers(0, 10**6), st.booleans())
def test_fuzz_mutated_valid_payloads(payload, flips, cut, truncate):
    decode_only_wire_errors(mutated(payload, flips, cut, truncate))


def mutated(payload: bytes, flips, cut: int, truncate: bool) -> bytes:
    """``payload`` with bytes overwritten at ``flips`` (position, byte) and, if ``truncate``, cut short."""
    data = bytearray(payload)
    for pos, byte in flips:
        data[pos % len(data)] = byte
    if truncate:
        data = data[: cut % (len(data) + 1)]
    return bytes(data)


msgpack_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=8) | st.binary(max_size=64),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)


@settings(max_examples=400)
@given(st.sampled_from(VALID), st.data())
def test_fuzz_field_values(payload, data):
    """Right envelope, random values in known fields: reaches the validators, not just msgpack."""
    d = msgpack.unpackb(payload)
    for name in data.draw(st.lists(st.sampled_from([k for k in d if k not in ("v", "kind")]), min_size=1, max_size=4)):
        d[name] = data.draw(msgpack_values)
    decode_only_wire_errors(msgpack.packb(d))


# --------------------------------------------------------------------------------------
# Recording -> frames
# --------------------------------------------------------------------------------------
def test_batches_from_arrays_cover_the_recording_once():
    n = 95
    t = 10 + np.arange(n) * 0.01
    acc, gyr, mag = (np.random.default_rng(i).normal(size=(n, 3)) for i in range(3))
    pt = np.array([9.0, 10.0, 10.09, 10.0900001, 10.19, 10.5, 20.0])  # before the first, on ends, after the last
    p = 1000 + np.arange(pt.size, dtype=float)
    batches = list(imu_batches_from_arrays("ff1", "dev", t, acc, gyr, mag, pt, p, carry="pocket", per_batch=10, seq0=4))
    assert [b.seq for b in batches] == list(range(4, 14))
    assert [b.n for b in batches] == [10] * 9 + [5]
    assert np.array_equal(np.concatenate([b.t for b in batches]), t)
    assert np.array_equal(np.concatenate([b.acc for b in batches]), acc)
    assert np.array_equal(np.concatenate([b.mag for b in batches]), mag)
    assert all(b.carry == "pocket" and b.responder == "ff1" for b in batches)
    owners = {float(x): b.seq for b in batches if b.pressure_t is not None for x in b.pressure_t}
    assert len(owners) == pt.size  # every pressure sample travels exactly once
    ends = [float(b.t[-1]) for b in batches]
    for x, seq in owners.items():
        k = seq - 4
        assert x <= ends[k] or k == len(batches) - 1
        assert k == 0 or x > ends[k - 1]
    assert owners[9.0] == 4 and owners[10.09] == 4 and owners[10.0900001] == 5 and owners[20.0] == 13


def test_batches_from_arrays_check_shapes():
    t = np.arange(5) * 0.01
    with pytest.raises(ValueError, match="acc has shape"):
        list(imu_batches_from_arrays("r", "d", t, np.zeros((4, 3)), np.zeros((5, 3))))
    with pytest.raises(ValueError, match="pressure_t must strictly increase: pressure_t\\[2\\]"):
        list(imu_batches_from_arrays("r", "d", t, np.zeros((5, 3)), np.zeros((5, 3)), pressure_t=[0.0, 0.02, 0.01],
                                     pressure=[1.0, 2.0, 3.0]))
    with pytest.raises(ValueError, match="t is empty"):
        list(imu_batches_from_arrays("r", "d", [], np.zeros((0, 3)), np.zeros((0, 3))))
    with pytest.raises(ValueError, match="per_batch"):
        list(imu_batches_from_arrays("r", "d", t, np.zeros((5, 3)), np.zeros((5, 3)), per_batch=0))


# --------------------------------------------------------------------------------------
# Keys and schema
# --------------------------------------------------------------------------------------
def test_keys():
    assert key("demo", "ff-1.a_b", "imu") == "firetrack/demo/ff-1.a_b/imu"
    assert key_all("demo", "pose") == "firetrack/demo/*/pose"
    for kind in wire.KEY_KINDS:
        assert parse_key(key("inc", "r1", kind)) == ("inc", "r1", kind)


@pytest.mark.parametrize("bad", ["a/b", "*", "**", "$x", "a#", "q?", "", "x" * 65, "sp ace", "é"])
def test_keys_refuse_bad_ids(bad):
    with pytest.raises(ValueError, match="must match"):
        key("demo", bad, "imu")
    with pytest.raises(ValueError, match="must match"):
        key(bad, "r1", "imu")


@pytest.mark.parametrize("k", ["firetrack/demo/r1", "firetrack/demo/r1/imu/x", "other/demo/r1/imu",
                               "firetrack/demo/r1/teleport", "firetrack/demo/*/imu", "firetrack//r1/imu"])
def test_parse_key_refuses(k):
    with pytest.raises(ValueError):
        parse_key(k)


def test_key_refuses_unknown_kind():
    with pytest.raises(ValueError, match="unknown key kind"):
        key("demo", "r1", "gossip")


@given(ids, ids, st.sampled_from(wire.KEY_KINDS))
def test_key_round_trip(incident, responder, kind):
    assert parse_key(key(incident, responder, kind)) == (incident, responder, kind)


def test_json_schema_describes_every_kind():
    doc = json.loads(json.dumps(json_schema()))  # plain JSON
    assert set(doc["$defs"]) >= {"imu", "fix", "pose", "status"}
    for kind, cls in wire.MESSAGE_TYPES.items():
        d = doc["$defs"][kind]
        assert d["properties"]["kind"]["const"] == kind and d["properties"]["v"]["const"] == SCHEMA_VERSION
        assert set(d["required"]) == {"v", "kind"} | {n for n, f in cls.model_fields.items() if f.is_required()}
        assert set(d["properties"]) == {"v", "kind"} | set(cls.model_fields)
    assert doc["$defs"]["imu"]["properties"]["acc"]["x-firetrack-array"]["shape"] == ["n", 3]
    assert doc["x-key-expressions"]["layout"] == "firetrack/{incident}/{responder}/{kind}"
    assert set(doc["x-key-expressions"]["kinds"]) == set(wire.KEY_KINDS)
    assert "little-endian" in doc["x-array-encoding"]["dtype"]


def _described(prop: dict) -> bool:
    """A property carries a description itself or in every non-null branch of its anyOf."""
    if "description" in prop or "const" in prop or "$ref" in prop:
        return True
    branches = [b for b in prop.get("anyOf", []) if b.get("type") != "null"]
    return bool(branches) and all(_described(b) for b in branches)


def test_every_field_of_every_message_says_what_it_is():
    """The integrator's contract (issue 18): each field's unit, frame or meaning is in the schema."""
    doc = json.loads(json.dumps(json_schema()))
    bare = [f"{name}.{field}" for name, d in doc["$defs"].items()
            for field, prop in d.get("properties", {}).items() if field not in ("v", "kind") and not _described(prop)]
    assert bare == []


def test_schema_command_writes_stdout_and_file(tmp_path):
    import typer

    from service.cli import schema as schema_cli

    app = typer.Typer()
    app.command("schema")(schema_cli.schema_command)
    app.command("other")(lambda: None)  # a group, so "schema" is a sub-command as in the real CLI
    runner = CliRunner()
    res = runner.invoke(app, ["schema"])
    assert res.exit_code == 0 and json.loads(res.stdout)["$defs"]["pose"]
    out = tmp_path / "sub" / "wire.json"
    res = runner.invoke(app, ["schema", "--out", str(out)])
    assert res.exit_code == 0 and json.loads(out.read_text()) == json_schema()
    blocked = tmp_path / "file"
    blocked.write_text("x")
    res = runner.invoke(app, ["schema", "--out", str(blocked / "wire.json")])
    assert res.exit_code == 1


def test_the_wire_module_needs_neither_gtsam_nor_zenoh():
    import subprocess
    import sys

    code = ("import sys, service.protocol.wire, service.core.gate; "
            "bad = [m for m in ('gtsam', 'zenoh', 'numba') if m in sys.modules]; assert not bad, bad")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr


# --------------------------------------------------------------------------------------
# The frames' fast path (issue 15): the same answers as the schema's own validation
# --------------------------------------------------------------------------------------
def same_answer_fast_and_schema(payload: bytes) -> None:
    """decode(expect=ImuBatch) with the msgspec fast path and without it: the same message,
    or the same reason and detail."""
    def run(fast):
        try:
            return decode(payload, expect=ImuBatch, fast=fast), None
        except WireError as e:
            return None, (e.reason, e.detail)
    fast, slow = run(True), run(False)
    assert fast[1] == slow[1]
    if slow[0] is not None:
        assert fast[0] == slow[0] and type(fast[0]) is ImuBatch
        for name in ("t", "acc", "gyr", "mag", "pressure_t", "pressure"):
            a = getattr(fast[0], name)
            assert a is None or (a.dtype == np.float64 and not a.flags.writeable)
        assert fast[0].model_dump().keys() == slow[0].model_dump().keys()


IMU_VALID = [encode(imu(n=5, mag=np.ones((5, 3)), pressure_t=[99.0], pressure=[970.0])), encode(imu(n=10)),
             encode(imu(n=10, mag=np.ones((10, 3)), pressure_t=[100.01, 100.05], pressure=[970.0, 970.1],
                        carry="handheld", utc_offset=1.7e9)),
             encode(imu(n=1)), encode(imu(n=40, rate=1900.0)), encode(imu(n=12, rate=6.0))]


@settings(max_examples=600)
@given(st.sampled_from(IMU_VALID), st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=6),
       st.integers(0, 10**6), st.booleans())
def test_fast_path_answers_mutated_frames_as_the_schema(payload, flips, cut, truncate):
    same_answer_fast_and_schema(mutated(payload, flips, cut, truncate))


@settings(max_examples=600)
@given(st.sampled_from(IMU_VALID), st.data())
def test_fast_path_answers_spoiled_fields_as_the_schema(payload, data):
    d = msgpack.unpackb(payload)
    names = [k for k in d] + ["mag", "pressure", "pressure_t", "utc_offset", "carry", "extra"]
    for name in data.draw(st.lists(st.sampled_from(names), min_size=1, max_size=4)):
        d[name] = data.draw(msgpack_values | st.binary(max_size=96) | st.floats() | st.sampled_from(
            [None, True, -1, 2**64 - 1, "handheld", "sim-001", "x" * 65, "a\n", float("nan"), 0, 1, 2]))
    same_answer_fast_and_schema(msgpack.packb(d))


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(imu_batches())
def test_fast_path_decodes_every_valid_frame(b):
    same_answer_fast_and_schema(encode(b))


@settings(max_examples=300)
@given(st.binary(max_size=600))
def test_fast_path_answers_random_bytes_as_the_schema(payload):
    same_answer_fast_and_schema(payload)


def test_fast_path_takes_the_common_frame():
    """The fast path is used, not just correct: a plain frame never reaches pydantic."""
    from service.protocol.codec import _fast_imu

    for p in IMU_VALID:
        assert _fast_imu(p) is not None
    spoiled = wire_map(imu(n=10))
    spoiled["t"] = np.array([0.0, 0.1, 0.1, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9]).tobytes()
    assert _fast_imu(msgpack.packb(spoiled)) is None

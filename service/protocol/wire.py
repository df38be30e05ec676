"""The wire schema: every message that crosses zenoh, defined once for both sides.

Imported by the service, the wearable publisher, the simulator, the recorder and the console,
so it depends on numpy, pydantic and msgpack only (never gtsam or zenoh).

Encoding
--------
A message is ONE msgpack map keyed by field name, plus two envelope keys:

* ``"v"``: the schema's major version (:data:`SCHEMA_VERSION`). Additions that old readers may
  ignore (a new optional field) keep the version; readers ignore keys they do not know. A
  change that breaks readers bumps it, and a reader rejects versions newer than its own
  (reason ``"version"``).
* ``"kind"``: ``"imu"``, ``"fix"``, ``"pose"``, ``"status"``, or ``"op"``, ``"audit"``,
  ``"access"`` (who did what: :mod:`service.protocol.actions`).

Optional fields that are ``None`` are left out of the map; a reader treats an absent key and
``nil`` alike. Sample arrays travel as msgpack ``bin``: packed little-endian IEEE-754 float64,
row-major (C order), never as lists, so a reader in any language takes them as one slice of
bytes. Their lengths follow from ``n = len(t) = len(bin(t)) / 8``: ``acc``, ``gyr`` and
``mag`` are ``n*3`` float64 (x0 y0 z0 x1 y1 z1 ...), ``pressure`` has as many values as
``pressure_t``, and :class:`Pose` ``cov`` is 4 float64, the 2x2 covariance row-major
(``[c_xx, c_xy, c_yx, c_yy]``, m²). In Python the arrays are read-only numpy float64 views of
the received bytes, shapes ``(n,)`` / ``(n, 3)`` / ``(2, 2)``.

Decoding checks, in this order, and names the first failure with one of
:data:`REJECT_REASONS` (the service counts rejects by reason and logs the detail): size,
msgpack validity, map, version, kind, the pydantic schema, array shapes (byte lengths whole
multiples of 8 and consistent with ``n``; ``1 <= n <= MAX_SAMPLES``), finiteness of every
number, strictly increasing ``t`` within a batch, and a sample rate judged from the batch's
median interval within ``[MIN_RATE_HZ, MAX_RATE_HZ]``. The same invariants hold for a message
built in Python (they raise pydantic's ``ValidationError`` there).

Key expressions
---------------
``firetrack/{incident}/{responder}/{kind}`` (:func:`key`), ``kind`` one of :data:`KEY_KINDS`:
``imu``, ``fix`` (wearable/operator -> service), ``pose``, ``status`` (service -> console),
``track`` (the service's queryable of a responder's track), ``presence`` (liveliness token of a
connected wearable) and ``truth`` (ground truth from a replayed recording or the simulator,
for scoring); ``op``, ``audit`` and ``access`` carry the actor's id instead of a responder's. Incident and responder ids match ``[A-Za-z0-9_.-]{1,64}``, so they never contain
a key-expression separator or wildcard (``/``, ``*``, ``$``, ``#``, ``?``).
"""
from __future__ import annotations

from service.protocol.actions import ACTIONS, Access, Audit, OperatorAction  # noqa: F401
from service.protocol.batches import imu_batches_from_arrays  # noqa: F401
from service.protocol.codec import (  # noqa: F401
    TRACK_FIELDS,
    decode,
    decode_track,
    encode,
    encode_track,
    error_location,
    json_schema,
)
from service.protocol.fixes import (  # noqa: F401
    FIX_MESSAGES,
    CheckpointFixMessage,
    GnssFixMessage,
    UwbFixMessage,
    register_fix_message,
)
from service.protocol.keys import (  # noqa: F401
    ACTOR_KINDS,
    ANCHOR_FIX,
    anchor_fix_all,
    anchor_fix_key,
    fix_sender,
    ID_PATTERN,
    KEY_KINDS,
    KEY_ROOT,
    KeyParts,
    is_valid_id,
    key,
    key_all,
    parse_key,
    read_key,
)
from service.protocol.schema import (  # noqa: F401
    CARRY_POSITIONS,
    LOST_CONTACT_S,
    MAX_PAYLOAD_BYTES,
    MAX_RATE_HZ,
    MAX_SAMPLES,
    MESSAGE_TYPES,
    MIN_RATE_HZ,
    REJECT_REASONS,
    SCHEMA_VERSION,
    Ack,
    Command,
    Fix,
    ImuBatch,
    Pose,
    Status,
    WireError,
    WireMessage,
)

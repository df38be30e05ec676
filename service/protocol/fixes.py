"""The fix messages, one model per source, as a pydantic discriminated union on ``source``.

==============  =========================================================================
source          fields (besides ``responder``, ``t``, ``time_base``, ``operator``)
==============  =========================================================================
``checkpoint``  ``name`` (a checkpoint of the incident) or ``x``, ``y`` (local ENU, m);
                optional ``floor``, ``sigma`` (m, 1-sigma)
``gnss``        ``lat``, ``lon`` (deg, WGS-84), ``accuracy`` (m, the receiver's 1-sigma radius)
``uwb``         ``anchor`` (an anchor id of the incident), ``range`` (m, 3D, to the anchor),
                ``sigma`` (m)
``ble``         one scan: ``beacons`` (ids, as the incident's ``beacons`` name them), ``rssi``
                (dBm, the mean heard from each over the scan), ``period`` (s, ending at ``t``)
==============  =========================================================================

A new source (a BLE beacon, a door sensor) is a subclass of :class:`Fix` with ``source:
Literal["name"]`` and one :func:`register_fix_message` call; the codec then decodes it, and
the JSON Schema (``firetrack schema``) lists it.
"""
from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator
from pydantic_core import PydanticCustomError

from service.protocol.arrays import Finite
from service.protocol.schema import FIX_MESSAGES, Fix, register_fix_message  # noqa: F401  (re-exported)


class CheckpointFixMessage(Fix):
    """The responder stands at a known point (an operator at a door, a tag reader)."""

    SOURCE: ClassVar[str] = "checkpoint"
    source: Literal["checkpoint"] = "checkpoint"
    x: Finite | None = Field(None, description="m, local ENU east")
    y: Finite | None = Field(None, description="m, local ENU north")
    floor: int | None = Field(None, description="the floor the responder is on (anchors the floor estimate)")
    name: str | None = Field(None, min_length=1, max_length=128, description="a checkpoint of the incident config")
    sigma: Finite | None = Field(None, gt=0.0, description="m, 1-sigma per axis")

    @model_validator(mode="after")
    def _where(self) -> CheckpointFixMessage:
        if (self.x is None) != (self.y is None):
            raise PydanticCustomError("fix_fields", "a checkpoint fix gives x and y together")
        if self.name is None and self.x is None:
            raise PydanticCustomError("fix_fields", "a checkpoint fix needs a checkpoint name or x and y")
        return self


class GnssFixMessage(Fix):
    """A satellite position of the responder."""

    SOURCE: ClassVar[str] = "gnss"
    source: Literal["gnss"] = "gnss"
    lat: Finite = Field(ge=-90.0, le=90.0, description="deg, WGS-84")
    lon: Finite = Field(ge=-180.0, le=180.0, description="deg, WGS-84")
    accuracy: Finite = Field(gt=0.0, description="m, the receiver's horizontal 1-sigma radius")


class UwbFixMessage(Fix):
    """A measured distance from the responder's tag to a UWB anchor of the incident."""

    SOURCE: ClassVar[str] = "uwb"
    source: Literal["uwb"] = "uwb"
    anchor: str = Field(min_length=1, max_length=128, description="an anchor id of the incident config")
    range: Finite = Field(ge=0.0, description="m, the 3D distance tag to anchor")
    sigma: Finite = Field(gt=0.0, description="m, 1-sigma of the range")


MAX_SCAN_BEACONS = 64  # beacons one scan may name


class BleFixMessage(Fix):
    """One BLE scan of the responder's wearable: the beacons it heard and how strongly."""

    SOURCE: ClassVar[str] = "ble"
    source: Literal["ble"] = "ble"
    beacons: list[str] = Field(min_length=1, max_length=MAX_SCAN_BEACONS,
                               description="beacon ids (MAC, or uuid:major:minor) as the incident config names them")
    rssi: list[Finite] = Field(min_length=1, max_length=MAX_SCAN_BEACONS,
                               description="dBm, the mean received strength of each beacon over the scan")
    period: Finite = Field(0.0, ge=0.0, le=60.0, description="s, the scan's length, ending at t")

    @model_validator(mode="after")
    def _paired(self) -> BleFixMessage:
        if len(self.beacons) != len(self.rssi):
            raise PydanticCustomError("fix_fields", "a ble fix gives one rssi per beacon")
        for b in self.beacons:
            if not 0 < len(b) <= 128:
                raise PydanticCustomError("fix_fields", "a beacon id has 1 to 128 characters")
        for v in self.rssi:
            if not -127.0 <= v <= 20.0:
                raise PydanticCustomError("fix_fields", f"rssi {v} dBm is outside -127..20")
        return self


for _m in (CheckpointFixMessage, GnssFixMessage, UwbFixMessage, BleFixMessage):
    register_fix_message(_m)

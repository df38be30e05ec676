"""Who did what: operator actions, the service's verdict on them, and the access policy.

Three wire messages whose key names the *actor* (``firetrack/{incident}/{actor}/{kind}``,
see :mod:`service.protocol.keys`):

=========  =========================  ================================================================
kind       direction                  what
=========  =========================  ================================================================
``op``     console/operator → service  :class:`OperatorAction`: a fix, a new checkpoint, an alarm
                                      acknowledged, a roll call (PAR) or evacuation order issued. ``operator``
                                      is the person logged in at the console; the key's actor is the
                                      console's (or operator's) certificate, bound by the router's ACL.
``audit``  service → consoles         :class:`Audit`: what the service made of an action or of a
                                      device's checkpoint fix (accepted, refused and why, flagged as an
                                      implausible jump). Recorded with everything the service publishes.
``access`` service (recorded only)    :class:`Access`: the policy the core enforces from then on (which
                                      identities may act as operators, which are revoked). Fed to the
                                      core like any input, so ``reprocess`` of a recording refuses
                                      exactly what the live service refused.
=========  =========================  ================================================================

A fix inside an action travels as its own encoded :class:`service.protocol.schema.Fix`
(``fix``: msgpack bytes), so every fix source and its validation work unchanged.
"""
from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator
from pydantic_core import PydanticCustomError

from service.protocol.arrays import Finite, Id
from service.protocol.schema import MESSAGE_TYPES, WireMessage

ACTIONS = ("fix", "checkpoint", "ack", "par", "evacuate", "beacon")
OUTCOMES = ("accepted", "refused", "recorded")


class OperatorAction(WireMessage):
    """One thing a person did at a console (console/operator → service, ``.../{actor}/op``).

    ``fix``: ``responder`` and ``fix`` (an encoded Fix for that responder). ``checkpoint``:
    ``name``, ``x``, ``y``, ``floor`` of a point the operator named. ``ack``: ``responder`` and
    ``alarm`` (the alarm acknowledged). ``par`` (a roll call) and ``evacuate`` (an evacuation
    order): ``order``, the id of the :class:`service.protocol.schema.Command` sent to each of
    ``responders``' wearables (on their ``.../command`` keys, which name no sender: this action
    is the record of who issued it). ``beacon``: ``responder`` dropped a beacon named ``name``
    (the id its scans give) where they stand now: the service places it at their current
    estimate, on their floor, with their position's uncertainty, and later scans of it by
    anyone are ``ble`` fixes (a breadcrumb). ``utc`` is the console's clock when the person acted.
    """

    KIND: ClassVar[str] = "op"
    action: Literal["fix", "checkpoint", "ack", "par", "evacuate", "beacon"] = Field(description="what the person did")
    operator: str = Field(min_length=1, max_length=128, description="the person logged in at the console")
    utc: Finite = Field(description="s, Unix time UTC of the console's clock when the person acted")
    responder: Id | None = Field(None, description="actions fix, ack: the responder it concerns")
    fix: bytes | None = Field(None, max_length=64 * 1024, description="action fix: an encoded Fix")
    alarm: str | None = Field(None, max_length=64, description="action ack: the alarm acknowledged")
    order: str | None = Field(None, max_length=64, description="actions par, evacuate: the order's id")
    responders: list[Id] | None = Field(None, max_length=10_000, description="actions par, evacuate: to whom")
    name: str | None = Field(None, max_length=128, description="action checkpoint: its name; beacon: the id scans name it by")
    x: Finite | None = Field(None, description="action checkpoint: m, east of the incident origin (ENU)")
    y: Finite | None = Field(None, description="action checkpoint: m, north of the incident origin (ENU)")
    floor: int | None = Field(None, description="action checkpoint: floor number (0 = ground, -1 = first basement)")
    note: str | None = Field(None, max_length=512, description="free text the operator added, kept in the recording")

    @model_validator(mode="after")
    def _fields_of_action(self) -> OperatorAction:
        need = {"fix": ("responder", "fix"), "checkpoint": ("name", "x", "y", "floor"),
                "ack": ("responder", "alarm"), "par": ("order", "responders"),
                "evacuate": ("order", "responders"), "beacon": ("responder", "name")}[self.action]
        missing = [n for n in need if getattr(self, n) is None]
        if missing:
            raise PydanticCustomError("action_fields", f"a {self.action} action needs {', '.join(missing)}")
        return self


class Audit(WireMessage):
    """The service's verdict on an operator action, or on a device's checkpoint fix that it
    flagged (service → consoles, ``.../{actor}/audit``).

    ``outcome``: ``accepted`` (the fix goes to the responder's track), ``refused`` (it never
    reaches the track; ``reason`` says why) or ``recorded`` (an action without a track effect:
    checkpoint, ack, par, evacuate). ``flags`` holds ``implausible_jump`` when the fix puts the responder
    ``jump_m`` from where it was, further than ``walkable_m``, what a person can cover in the
    time since (:mod:`service.core.plausibility`); an authorised fix is still accepted.
    """

    KIND: ClassVar[str] = "audit"
    actor: Id = Field(description="who published: the console/operator certificate, or the wearable")
    operator: str | None = Field(None, max_length=128, description="the person logged in, for an operator action")
    action: Literal["fix", "checkpoint", "ack", "par", "evacuate", "beacon", "device_fix"] = Field(
        description="the operator action judged, or device_fix for a wearable's own checkpoint fix")
    outcome: Literal["accepted", "refused", "recorded"] = Field(
        description="accepted: goes to the track; refused: never reaches it (see reason); recorded: no track effect")
    responder: Id | None = Field(None, description="the responder whose track it concerns")
    order: str | None = Field(None, max_length=64, description="par, evacuate: the order's id")
    reason: str | None = Field(None, max_length=64, description="refused: a short machine-readable reason")
    detail: str | None = Field(None, max_length=512, description="a sentence for people: what and why")
    flags: list[str] = Field(default_factory=list, description="warnings on an accepted action, e.g. implausible_jump")
    jump_m: Finite | None = Field(None, description="m, from the reference position to the fix")
    walkable_m: Finite | None = Field(None, description="m, the most a person could have covered since")
    t: Finite | None = Field(None, description="s, device clock: the fix's time")
    utc: Finite | None = Field(None, description="s, Unix time UTC: when the operator acted")
    received: Finite = Field(description="s, Unix time UTC of the service's clock when it took the message")


class Access(WireMessage):
    """The access policy the core enforces from this message on (service, recorded).

    ``enforce`` false: every identity may do everything (the insecure demo). True: operator
    actions are taken only from ``operators`` (console, operator and service identities of the
    roster), and nothing is taken from a ``revoked`` identity (its frames, fixes, presence
    and actions are refused before they reach a track). ``wearables`` join the intake's roster
    (:mod:`service.core.intake`), so a wearable added to the roster mid-incident is admitted.
    """

    KIND: ClassVar[str] = "access"
    enforce: bool = Field(description="false: everyone may do everything (insecure demo); true: the lists below apply")
    operators: list[Id] = Field(default_factory=list, description="identities whose operator actions are taken")
    revoked: list[Id] = Field(default_factory=list, description="identities from which nothing is taken")
    wearables: list[Id] = Field(default_factory=list, description="the roster's wearable identities: always admitted "
                                "as responders (with serve --roster-only, they and the incident config's roster only)")
    source: str | None = Field(None, max_length=512, description="where the policy came from (the roster file)")


MESSAGE_TYPES.update({m.KIND: m for m in (OperatorAction, Audit, Access)})

"""Absolute position information that corrects a responder's dead-reckoned track: one module
per fix type (see :mod:`.base`). Domain objects in the incident's local ENU frame, not wire
messages."""
from service.fusion.fixes.base import FixContext, FixRejected
from service.fusion.fixes.ble import BleScan
from service.fusion.fixes.checkpoint import CheckpointFix
from service.fusion.fixes.gnss import GnssFix
from service.fusion.fixes.uwb import UwbRange

Fix = CheckpointFix | GnssFix | UwbRange | BleScan

__all__ = ["BleScan", "CheckpointFix", "Fix", "FixContext", "FixRejected", "GnssFix", "UwbRange"]

"""Factor-graph fusion of a responder's PDR steps with checkpoint, GNSS and UWB fixes (gtsam).

One code path for the live service and the offline evaluation: make a :class:`TrackFusion`,
``start()`` it, then feed ``add_step(StepEvent)`` and ``add_fix(fix)`` in time order; read
``live`` (what is published) and ``smoothed_track()`` (the best estimate in hindsight).
"""
from service.fusion.fixes import CheckpointFix, Fix, GnssFix, UwbRange
from service.fusion.graph import FusedPose, FusionEvent, FusionSettings, TrackFusion

__all__ = ["CheckpointFix", "Fix", "FusedPose", "FusionEvent", "FusionSettings", "GnssFix", "TrackFusion", "UwbRange"]

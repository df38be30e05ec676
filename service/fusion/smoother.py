"""The fixed-lag smoother every track runs on: gtsam's incremental fixed-lag smoother (iSAM2).

Relinearisation thresholds per kind of variable (Kaess et al., "iSAM2", IJRR 31(2), 2012,
§5: a variable is relinearised when its update exceeds the threshold): poses ``x`` and
anchors ``a`` by ``relinearize_position_m`` (m) and ``relinearize_heading_rad``, the step-length
scale ``s`` by ``relinearize_scale``, the PDR-heading offset ``c`` by ``relinearize_heading_rad``.
Factor slots of marginalised factors are reused, so memory stays bounded over a long incident.
"""
from __future__ import annotations

import gtsam
import numpy as np

from service.fusion.settings import FusionSettings


def new_smoother(s: FusionSettings) -> gtsam.IncrementalFixedLagSmoother:
    """A smoother with a window of ``s.lag_s`` seconds and the thresholds above."""
    params = gtsam.ISAM2Params()
    thresholds = gtsam.ISAM2ThresholdMap()
    thresholds.insert(("x", np.array([s.relinearize_position_m, s.relinearize_position_m, s.relinearize_heading_rad])))
    thresholds.insert(("a", np.array([s.relinearize_position_m, s.relinearize_position_m])))
    thresholds.insert(("s", np.array([s.relinearize_scale])))
    thresholds.insert(("c", np.array([s.relinearize_heading_rad])))
    params.setRelinearizeThreshold(thresholds)
    params.relinearizeSkip = int(s.relinearize_skip)
    params.findUnusedFactorSlots = True  # reuse slots of marginalised factors: bounded memory
    return gtsam.IncrementalFixedLagSmoother(s.lag_s, params)

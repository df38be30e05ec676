"""gtsam keys of the fusion graph's variables, one letter per kind."""
from __future__ import annotations

import gtsam


def X(row: int) -> int:
    """gtsam key of the pose in history row ``row``."""
    return gtsam.symbol("x", row)


def A(n: int) -> int:
    """gtsam key of anchor variable ``n``."""
    return gtsam.symbol("a", n)


def C(n: int) -> int:
    """gtsam key of the PDR-heading offset variable ``n`` (service/fusion/heading_evidence.py)."""
    return gtsam.symbol("c", n)


def S(n: int) -> int:
    """gtsam key of step-length scale variable ``n``."""
    return gtsam.symbol("s", n)

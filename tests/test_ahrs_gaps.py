"""A gap in the samples: the decoupled filter levels again at once (how the sensor turned in the
gap is unknown), instead of slewing its stale memory of gravity at acc_rate_max."""
from __future__ import annotations

import numpy as np

from pdr.ahrs import make_filter
from pdr.quaternion import rotate

G = 9.81


def _tilt_deg(q: np.ndarray, acc_body: np.ndarray) -> float:
    """Angle between the estimated vertical of the body's specific force and up."""
    up = rotate(q, acc_body)
    return float(np.degrees(np.arccos(np.clip(up[2] / np.linalg.norm(up), -1.0, 1.0))))


def test_a_gap_in_which_the_phone_was_turned_is_levelled_again_within_the_acc_time_constant():
    rate = 100.0
    t1 = np.arange(0.0, 10.0, 1 / rate)
    t2 = np.arange(11.5, 16.0, 1 / rate)  # 1.5 s with no sample: the page was hidden, the phone turned over
    flat, on_side = np.array([0.0, 0.0, G]), np.array([0.0, G, 0.0])  # turned 90 deg about x in the gap
    f = make_filter("decoupled", {"rest_time": float("inf")})
    f.update(t1, np.tile(flat, (t1.size, 1)), np.zeros((t1.size, 3)))
    q = f.update(t2, np.tile(on_side, (t2.size, 1)), np.zeros((t2.size, 3)))
    settle = int(rate * (f.settings.tau_acc + 0.5))
    tilt = _tilt_deg(q[settle], on_side)
    # kept, the stale memory would slew at acc_rate_max (0.03 rad/s): about 80 deg still to go here
    assert tilt < 2.0, f"{tilt:.1f} deg off level {settle / rate:.1f} s after the gap"


def test_samples_closer_than_max_dt_are_not_a_gap():
    """Browser jitter (a late event of 0.3 s) keeps the filter's memory: the same result as
    without the late event's extra delay, up to the interval's own effect."""
    rate = 60.0
    t = np.arange(0.0, 8.0, 1 / rate)
    t_late = t.copy()
    t_late[t.size // 2:] += 0.3  # one interval of 0.317 s < max_dt 0.5 s
    acc = np.tile([0.0, 0.0, G], (t.size, 1))
    a = make_filter("decoupled").update(t, acc, np.zeros((t.size, 3)))
    b = make_filter("decoupled").update(t_late, acc, np.zeros((t.size, 3)))
    assert np.allclose(a, b, atol=1e-9)

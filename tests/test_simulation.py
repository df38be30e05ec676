"""Simulated walkers (pdr.simulation): streaming, physics consistency, and the repo's own
detectors, filters and altimeter run on the simulated streams against the known truth."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pdr import quaternion as quat
from pdr.ahrs import make_filter
from pdr.constants import GRAVITY
from pdr.heading import wrap
from pdr.height import AltimeterSettings, BarometricAltimeter, metres_per_hpa
from pdr.simulation import (
    Route,
    SimBatch,
    SimulatedWalker,
    WalkerFleet,
    WalkerSettings,
    random_route,
    simulate_walk,
)
from pdr.steps import make_detector, norm_minus_gravity

FIELDS = ("t", "acc", "gyr", "mag", "pressure_t", "pressure", "t_truth", "x", "y", "z", "floor", "heading",
          "step_count", "q")

# no noise, no bias: what is left must be exactly consistent
CLEAN = WalkerSettings(gyro_noise=0.0, gyro_bias=0.0, acc_noise=0.0, mag_noise=0.0, pressure_noise_hpa=0.0)
# ... and no gait either: the specific force is then the track's own acceleration plus gravity
SMOOTH = dataclasses.replace(CLEAN, vertical_acc_amplitude=0.0, forward_acc_amplitude=0.0, lateral_acc_amplitude=0.0,
                             pitch_sway_rad=0.0, roll_sway_rad=0.0, yaw_sway_rad=0.0)

# a corridor loop on floor 0, a flight of stairs to floor 1, a pause, a U-turn (taken standing), back
BUILDING_ROUTE = Route(
    waypoints=[(0, 0), (20, 0), (20, 10), (6, 10), (6, 15), (1, 15), (15, 15), (15, 8)],
    floors=[0, 0, 0, 0, 1, 1, 1, 1],
    pauses=[0, 0, 4.0, 0, 0, 0, 0, 0],
)


def batches(walker: SimulatedWalker, total: int, sizes=(7, 10, 33)) -> SimBatch:
    parts, done, i = [], 0, 0
    while done < total:
        m = min(sizes[i % len(sizes)], total - done)
        parts.append(walker.next_batch(m))
        done, i = done + m, i + 1
    return SimBatch.concatenate(parts)


def assert_same(a: SimBatch, b: SimBatch, tol: float = 0.0) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape, name
        np.testing.assert_allclose(x, y, rtol=tol, atol=tol, err_msg=name)


def yaw_of_forward(q: np.ndarray) -> np.ndarray:
    """ENU yaw of the phone's forward (body y) axis."""
    f = quat.rotate(q, np.array([0.0, 1.0, 0.0]))
    return np.arctan2(f[:, 1], f[:, 0])


@pytest.mark.bitexact
# -- streaming ---------------------------------------------------------------------------------
@pytest.mark.parametrize("route", [None, BUILDING_ROUTE], ids=["random", "building"])
def test_batches_concatenate_to_one_call(route):
    one = SimulatedWalker("ff", route, rng_seed=5).next_batch(6000)
    assert_same(one, batches(SimulatedWalker("ff", route, rng_seed=5), 6000))
    assert one.step_count[-1] > 50  # it did walk


def test_fleet_walker_equals_lone_walker():
    fleet = WalkerFleet(4, seed=9)
    parts = [fleet.next_arrays(25) for _ in range(80)]
    for i in range(4):
        alone = SimulatedWalker(fleet.responders[i], None, rng_seed=fleet.seeds[i]).next_batch(2000)
        assert_same(alone, SimBatch.concatenate([p.walker(i) for p in parts]))


def test_fleet_interruptions_match_the_lone_walker():
    fleet = WalkerFleet(3, seed=2)
    parts = [fleet.next_arrays(10) for _ in range(50)]
    fleet.stand_still(1, 4.0, at=9.0)
    fleet.collapse(2, at=12.5)
    parts += [fleet.next_arrays(10) for _ in range(150)]
    for i, (seconds, collapse) in enumerate([(None, None), (4.0, None), (None, 12.5)]):
        alone = SimulatedWalker(fleet.responders[i], None, rng_seed=fleet.seeds[i], collapse_at=collapse)
        if seconds:
            alone.stand_still(seconds, at=9.0)
        got = SimBatch.concatenate([p.walker(i) for p in parts])
        assert_same(alone.next_batch(2000), got)
        plain = SimulatedWalker(fleet.responders[i], None, rng_seed=fleet.seeds[i]).next_batch(2000)
        assert np.allclose(plain.x, got.x) == (i == 0)  # the interruptions did change the walk


@pytest.mark.bitexact
def test_stand_still_and_collapse_are_batching_independent():
    def run(sizes):
        w = SimulatedWalker("ff", None, rng_seed=3)
        w.stand_still(5.0, at=17.3)
        w.collapse(at=61.7)
        return batches(w, 7000, sizes)

    assert_same(run((10,)), run((7, 33, 101)))


def test_interruptions_in_the_past_are_refused():
    w = SimulatedWalker("ff", None, rng_seed=3)
    w.next_batch(500)
    with pytest.raises(ValueError, match="before its next sample"):
        w.collapse(at=2.0)
    with pytest.raises(ValueError, match="seconds > 0"):
        w.stand_still(0.0)


def test_different_seeds_differ_and_noise_is_independent():
    a = simulate_walk(None, WalkerSettings(), 20.0, seed=1)
    b = simulate_walk(None, WalkerSettings(), 20.0, seed=2)
    assert not np.allclose(a.x, b.x)
    still = slice(0, 190)  # both stand for the first 2 s
    na, nb = a.acc[still] - a.acc[still].mean(0), b.acc[still] - b.acc[still].mean(0)
    assert abs(np.corrcoef(na[:, 0], nb[:, 0])[0, 1]) < 0.25


# -- the repository's step detector -------------------------------------------------------------
@pytest.mark.parametrize("rate_hz", [50.0, 100.0])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_norm_detector_counts_the_true_steps(rate_hz, seed):
    b = simulate_walk(None, WalkerSettings(rate_hz=rate_hz), 200.0, seed=seed)
    det = make_detector("norm")
    found = len(det.update(b.t, norm_minus_gravity(b.acc)) + det.finish())
    true = int(b.step_count[-1])
    assert true > 200
    assert abs(found - true) <= 0.02 * true, (found, true)


def test_cadence_and_step_length_are_what_the_walker_draws():
    w = SimulatedWalker("ff", Route([(0, 0), (60, 0)], [0, 0]), rng_seed=4)
    b = w.next_batch(6000)
    walking = (b.t > w.settings.initial_still_s + 1.0) & (b.x < 55.0)
    steps = np.diff(b.step_count[walking]).sum()
    cadence = steps / (b.t[walking][-1] - b.t[walking][0])
    assert cadence == pytest.approx(w.traits.cadence_hz, rel=0.08)
    assert b.x[-1] == pytest.approx(60.0, abs=1e-6)
    assert 60.0 / b.step_count[-1] == pytest.approx(w.traits.step_length_m, rel=0.03)


# -- physics ---------------------------------------------------------------------------------------
def test_at_rest_the_accelerometer_reads_gravity_and_the_gyro_its_bias():
    s = WalkerSettings(initial_still_s=20.0)
    w = SimulatedWalker("ff", None, s, rng_seed=8)
    b = w.next_batch(1900)
    assert np.ptp(b.x) == 0.0 and np.ptp(b.y) == 0.0
    n = len(b.t)
    assert np.linalg.norm(b.acc.mean(0)) == pytest.approx(GRAVITY, abs=4 * s.acc_noise / math.sqrt(n))
    np.testing.assert_allclose(b.gyr.mean(0), w.gyro_bias, atol=4 * s.gyro_noise / math.sqrt(n))
    np.testing.assert_allclose(b.gyr.std(0), s.gyro_noise, rtol=0.1)
    np.testing.assert_allclose(b.acc.std(0), s.acc_noise, rtol=0.1)
    np.testing.assert_allclose(b.mag.std(0), s.mag_noise, rtol=0.1)
    np.testing.assert_allclose(quat.rotate(b.q, b.acc).mean(0), [0, 0, GRAVITY], atol=0.01)


@pytest.mark.parametrize("seed", [0, 1])
def test_magnetometer_and_gyro_agree_with_the_attitude(seed):
    w = SimulatedWalker("ff", None, CLEAN, rng_seed=seed)
    parts = [w.next_batch(6000)]
    w.stand_still(3.0)
    parts.append(w.next_batch(6000))
    b = SimBatch.concatenate(parts)
    np.testing.assert_allclose(quat.rotate(b.q, b.mag), np.broadcast_to(CLEAN.field, b.mag.shape), atol=1e-5)
    # integrate the gyro (midpoint rate) from the true start: it must follow the true attitude
    dt = 1.0 / CLEAN.rate_hz
    steps = quat.from_rotation_vector(0.5 * (b.gyr[1:] + b.gyr[:-1]) * dt)
    q = b.q[0].copy()
    worst = 0.0
    for i in range(1, len(b.t)):  # a test oracle, not a hot path
        q = quat.multiply(q, steps[i - 1])
        if i % 50 == 0:
            q = quat.normalize(q)
            worst = max(worst, float(quat.angle_between(b.q[i], q)))
    assert math.degrees(worst) < 0.05


def test_specific_force_is_the_track_acceleration_plus_gravity():
    b = simulate_walk(BUILDING_ROUTE, SMOOTH, 120.0, seed=2)
    dt = 1.0 / SMOOTH.rate_hz
    p = np.c_[b.x, b.y, b.z]
    a_track = (p[2:] - 2 * p[1:-1] + p[:-2]) / dt**2
    a_sim = quat.rotate(b.q, b.acc)[1:-1] - [0.0, 0.0, GRAVITY]
    err = np.abs(a_track - a_sim)
    assert np.percentile(err, 99) < 0.01  # m/s²; the rest: acceleration steps (start, stairs) seen by the finite difference
    assert err.max() < 2.5
    # integrating the specific force (minus g) from standstill gives the track's velocity throughout
    a = quat.rotate(b.q, b.acc) - [0.0, 0.0, GRAVITY]
    v_int = np.vstack([np.zeros(3), np.cumsum(0.5 * (a[1:] + a[:-1]) * dt, axis=0)])
    v_track = np.gradient(p, dt, axis=0)
    assert np.abs(v_int - v_track).max() < 0.02  # m/s
    assert np.linalg.norm(v_track[:, :2], axis=1).max() < 2.0 and np.abs(v_track[:, 2]).max() > 0.2  # walked the stairs


def test_fscf_tracks_the_simulated_heading():
    b = simulate_walk(None, WalkerSettings(), 150.0, seed=1)
    q = make_filter("fscf").update(b.t, b.acc, b.gyr, b.mag)
    err = np.degrees(wrap(yaw_of_forward(q) - yaw_of_forward(b.q)))[b.t > 20.0]
    assert np.sqrt(np.mean(err**2)) < 3.0 and np.abs(err).max() < 6.0
    # the heading truth is the walking direction; the phone's forward axis only sways about it
    sway = np.degrees(wrap(yaw_of_forward(b.q) - b.heading))
    assert np.abs(sway).max() < 3.0


# -- truth -----------------------------------------------------------------------------------------
def test_path_length_is_steps_times_step_length():
    route = Route([(0, 0), (30, 0), (30, 12), (0, 12), (0, 0)], [0] * 5)
    w = SimulatedWalker("ff", route, rng_seed=6)
    b = w.next_batch(12000)
    path = np.hypot(np.diff(b.x), np.diff(b.y)).sum()
    legs = len(route) - 1
    lam = w.traits.step_length_m
    assert abs(path - b.step_count[-1] * lam) <= 0.5 * lam * legs  # each leg is a whole number of steps
    assert 84.0 - 4 * 1.0 < path < 84.0  # corners taken in a curve cut the 84 m loop a little
    assert np.hypot(b.x[-1], b.y[-1]) < 1e-6  # and it ends where the route ends
    assert np.all(np.diff(b.step_count) >= 0) and np.diff(b.step_count).max() == 1


def test_floor_change_shows_in_pressure_and_the_altimeter_recovers_height():
    s = WalkerSettings()
    w = SimulatedWalker("ff", BUILDING_ROUTE, s, rng_seed=3)
    b = w.next_batch(15000)
    assert b.floor[0] == 0 and b.floor[-1] == 1
    assert b.z[-1] == pytest.approx(s.floor_height_m, abs=1e-9)
    # standing at the start and at the end: the pressure differs by the barometric gradient
    p_start = b.pressure[b.pressure_t < s.initial_still_s - 0.1].mean()
    p_end = b.pressure[b.pressure_t > b.pressure_t[-1] - 20.0].mean()
    assert np.ptp(b.z[b.t > b.t[-1] - 20.0]) == 0.0
    gradient = 1.0 / metres_per_hpa(s.base_pressure_hpa)  # hPa per metre, about 0.12
    assert gradient == pytest.approx(0.12, abs=0.005)
    assert p_start - p_end == pytest.approx(gradient * s.floor_height_m, rel=0.03)
    # the repo's altimeter recovers the height wherever the true height has been steady for 8 s
    h = BarometricAltimeter(AltimeterSettings(), start_height_m=0.0).update(b.pressure_t, b.pressure)
    z = np.interp(b.pressure_t, b.t, b.z)
    moved = b.t[1:][np.diff(b.z) != 0]  # times the height changed
    last_move = np.r_[-np.inf, moved][np.searchsorted(moved, b.pressure_t, side="right")]
    steady = (b.pressure_t - last_move > 8.0) & (b.pressure_t > 5.0)
    assert steady.sum() > 100 and (z[steady] > 1.0).any()
    assert np.abs(h[steady] - z[steady]).max() < 0.5


def test_pause_in_the_route_is_stood_out():
    b = simulate_walk(BUILDING_ROUTE, WalkerSettings(), 60.0, seed=1)
    at = (np.hypot(b.x - 20.0, b.y - 10.0) < 1e-9)
    assert at.any()
    # standing at waypoint 2: the pause (4 s) plus the turn on the spot is at least 4 s
    assert at.sum() / WalkerSettings().rate_hz >= 4.0


# -- man down ---------------------------------------------------------------------------------------
def test_collapsed_walker_lies_still_with_only_sensor_noise():
    s = WalkerSettings()
    w = SimulatedWalker("ff", None, s, rng_seed=4, collapse_at=40.0)
    b = w.next_batch(9000)
    before = (b.t > 30.0) & (b.t < 39.0)
    after = b.t > 40.0 + s.fall_s
    assert b.gyr[before].std(0).max() > 10 * s.gyro_noise  # walking before
    np.testing.assert_allclose(b.gyr[after].mean(0), w.gyro_bias, atol=4 * s.gyro_noise / math.sqrt(after.sum()))
    np.testing.assert_allclose(b.gyr[after].std(0), s.gyro_noise, rtol=0.1)
    np.testing.assert_allclose(b.acc[after].std(0), s.acc_noise, rtol=0.1)
    assert np.linalg.norm(b.acc[after].mean(0)) == pytest.approx(GRAVITY, abs=0.01)
    for name in ("x", "y", "z", "step_count"):
        assert np.ptp(getattr(b, name)[after]) == 0
    # the phone lies tipped over: its z axis is no longer up
    up = quat.rotate(b.q[after][-1], np.array([0.0, 0.0, 1.0]))
    assert up[2] == pytest.approx(math.cos(s.fall_pitch_rad), abs=0.05)


def test_stand_still_for_good_keeps_the_phone_upright_and_motionless():
    w = SimulatedWalker("ff", None, rng_seed=5)
    w.next_batch(3000)
    w.stand_still(math.inf)
    b = w.next_batch(3000)
    late = b.t > b.t[0] + 3.0
    assert np.ptp(b.x[late]) == 0 and np.ptp(b.step_count[late]) == 0
    assert b.gyr[late].std(0).max() < 1.2 * w.settings.gyro_noise
    assert quat.rotate(b.q[late][-1], np.array([0.0, 0.0, 1.0]))[2] > 0.99


# -- inputs ------------------------------------------------------------------------------------------
def test_bad_routes_and_settings_are_named():
    with pytest.raises(ValueError, match=r"waypoints must have shape"):
        Route([1, 2, 3], [0, 0, 0])
    with pytest.raises(ValueError, match=r"waypoints\[1\] is not finite"):
        Route([(0, 0), (np.nan, 1)], [0, 0])
    with pytest.raises(ValueError, match="floors must be integers"):
        Route([(0, 0), (1, 1)], [0, 0.5])
    with pytest.raises(ValueError, match="change floor without horizontal distance"):
        Route([(0, 0), (0, 0)], [0, 1])
    with pytest.raises(ValueError, match="cadence_hz"):
        WalkerSettings(cadence_hz=0.0)
    with pytest.raises(ValueError, match="bounds"):
        SimulatedWalker("ff", None, bounds=(5, 1, 0, 1))


def test_random_route_stays_inside_bounds():
    rng = np.random.default_rng(0)
    r = random_route(rng, bounds=(0, 30, 0, 20), floors=(-1, 2), n_waypoints=200)
    assert len(r) == 200
    assert (r.waypoints[:, 0] >= 0).all() and (r.waypoints[:, 0] <= 30).all()
    assert (r.waypoints[:, 1] >= 0).all() and (r.waypoints[:, 1] <= 20).all()
    assert r.floors.min() >= -1 and r.floors.max() <= 2 and np.abs(np.diff(r.floors)).max() == 1
    b = simulate_walk(None, WalkerSettings(), 300.0, seed=7, bounds=(0, 30, 0, 20), floors=(-1, 2))
    assert b.x.min() >= -1.0 and b.x.max() <= 31.0 and b.y.min() >= -1.0 and b.y.max() <= 21.0

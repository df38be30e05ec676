"""``firetrack bench fusion``: cost per step of the factor-graph fusion over a long synthetic incident.

A two-hour walk (≈14,000 steps at ≈1.9 steps/s) through corridors with right-angle turns,
dead-reckoned with a drifting gyro, a noisy step length and a compass that is sometimes
disturbed, corrected by a checkpoint every ``fix_every`` steps. The figures that matter: the
median time of ``add_step`` (the live path) and whether it stays flat — the last 1000 steps
against the first 1000 — because the smoother marginalises old poses.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import typer

from pdr.events import StepEvent
from service.protocol.terminal import out, print_json


@dataclass(frozen=True)
class SyntheticWalk:
    """True poses (row 0 = start) and the PDR's step events for them."""

    t: np.ndarray  # (n+1,) s
    x: np.ndarray  # (n+1,) m, true ENU east
    y: np.ndarray  # (n+1,) m, true ENU north
    heading: np.ndarray  # (n+1,) rad, true heading of travel
    events: list[StepEvent]


def synthetic_walk(steps: int, seed: int = 0, cadence_hz: float = 1.9, gyro_drift_deg_per_step: float = 0.05,
                   turn_noise_deg: float = 0.5, length_scale_error: float = 0.03, mag_sigma_deg: float = 6.0,
                   mag_disturbed_fraction: float = 0.3) -> SyntheticWalk:
    """A corridor walk: straight runs of 10-60 steps joined by ±90° turns (numpy, vectorised).

    The PDR's turn per step is the true turn plus a constant gyro drift and white noise; its
    length is the true length scaled by ``1 + length_scale_error`` plus noise; the compass is
    the true heading plus noise, and missing (NaN, as the PDR reports a disturbed field) on
    about ``mag_disturbed_fraction`` of the steps in runs.
    """
    rng = np.random.default_rng(seed)
    n = steps
    dt = rng.normal(1.0 / cadence_hz, 0.03 / cadence_hz, n).clip(0.3 / cadence_hz)
    t = np.r_[0.0, np.cumsum(dt)]
    runs = rng.integers(10, 61, size=n // 10 + 2)
    turn_at = np.cumsum(runs)
    turn_true = np.zeros(n)
    corners = turn_at[turn_at < n]
    turn_true[corners] = rng.choice([-math.pi / 2, math.pi / 2], size=len(corners))
    turn_true += rng.normal(0.0, math.radians(1.0), n)  # sway of the walking line
    heading = np.r_[0.0, np.cumsum(turn_true)]
    length = rng.normal(0.7, 0.05, n).clip(0.3)
    x = np.r_[0.0, np.cumsum(length * np.cos(heading[1:]))]
    y = np.r_[0.0, np.cumsum(length * np.sin(heading[1:]))]
    turn_meas = turn_true + math.radians(gyro_drift_deg_per_step) + rng.normal(0.0, math.radians(turn_noise_deg), n)
    length_meas = length * (1.0 + length_scale_error) + rng.normal(0.0, 0.03, n)
    pdr_heading = np.cumsum(turn_meas)
    mag = heading[1:] + rng.normal(0.0, math.radians(mag_sigma_deg), n)
    block = 25  # disturbed stretches come in runs of steps, as near a steel structure
    disturbed = np.repeat(rng.random(n // block + 1) < mag_disturbed_fraction, block)[:n]
    mag[disturbed] = math.nan
    mag_sigma = np.where(disturbed, math.inf, math.radians(mag_sigma_deg))
    turn_sigma = math.hypot(math.radians(turn_noise_deg), math.radians(gyro_drift_deg_per_step))
    events = [
        StepEvent(t=float(t[k + 1]), index=k + 1, length=float(length_meas[k]), length_sigma=0.05,
                  heading=float(pdr_heading[k]), heading_sigma=math.radians(10.0), heading_change=float(turn_meas[k]),
                  heading_change_sigma=turn_sigma, dz=0.0, dz_sigma=0.1, floor=0, on_stairs=False,
                  mag_heading=float(mag[k]), mag_heading_sigma=float(mag_sigma[k]))
        for k in range(n)
    ]
    return SyntheticWalk(t=t, x=x, y=y, heading=heading, events=events)


def bench_fusion(steps: int = 14000, fix_every: int = 100, seed: int = 0,
                 settings=None) -> dict:
    """Run the synthetic walk through :class:`TrackFusion`, timing every ``add_step`` and ``add_fix``.

    Times are CPU time of the calling thread (``*_ms``; the wall-clock median is reported too),
    medians because the machine is shared. ``fix_every`` <= 0 disables the checkpoints.
    ``final_error_m`` is the live pose against the truth after the last step (a checkpoint step
    when ``steps`` is a multiple of ``fix_every``); ``smoothed_rmse_m`` scores the whole
    smoothed track, frozen poses included.
    """
    from service.fusion import (  # gtsam: only when the benchmark runs
        CheckpointFix,
        TrackFusion,
    )

    walk = synthetic_walk(steps, seed)
    rng = np.random.default_rng(seed + 1)
    fusion = TrackFusion(settings)
    fusion.start(0.0, 0.0, 0.0, heading=0.0, heading_sigma=math.radians(5.0), position_sigma=0.3)
    step_ms = np.empty(steps)
    step_wall_ms = np.empty(steps)
    fix_ms = []
    # CPU time of this thread: gtsam's wheel is single-threaded (no TBB), and CPU time is robust
    # to the other jobs of a shared machine, which wall-clock time is not
    cpu, wall = time.thread_time, time.perf_counter
    t_begin = wall()
    for k, ev in enumerate(walk.events):
        w0, c0 = wall(), cpu()
        fusion.add_step(ev)
        step_ms[k] = (cpu() - c0) * 1e3
        step_wall_ms[k] = (wall() - w0) * 1e3
        if fix_every > 0 and (k + 1) % fix_every == 0:
            fix = CheckpointFix(t=ev.t, x=float(walk.x[k + 1] + rng.normal(0, 0.2)),
                                y=float(walk.y[k + 1] + rng.normal(0, 0.2)), sigma=0.3)
            c0 = cpu()
            fusion.add_fix(fix)
            fix_ms.append((cpu() - c0) * 1e3)
    total_s = wall() - t_begin
    live = fusion.live
    track = fusion.smoothed_track()
    head = step_ms[: min(1000, steps)]
    tail = step_ms[-min(1000, steps):]
    return {
        "steps": steps,
        "fix_every": fix_every,
        "median_update_ms": float(np.median(step_ms)),
        "p99_update_ms": float(np.percentile(step_ms, 99)),
        "first_1000_median_ms": float(np.median(head)),
        "last_1000_median_ms": float(np.median(tail)),
        "ratio_last_first": float(np.median(tail) / np.median(head)),
        "median_update_wall_ms": float(np.median(step_wall_ms)),
        "total_s": total_s,
        "final_error_m": float(math.hypot(live.x - walk.x[-1], live.y - walk.y[-1])),
        "fix_median_ms": float(np.median(fix_ms)) if fix_ms else None,
        "smoothed_rmse_m": float(np.sqrt(np.mean((track["x"] - walk.x) ** 2 + (track["y"] - walk.y) ** 2))),
        "window_variables": fusion.window_variables,
        "walk_duration_s": float(walk.t[-1]),
    }


def fusion_command(
    steps: int = typer.Option(14000, "--steps", help="number of steps of the synthetic walk (≈1.9 steps/s)"),
    fix_every: int = typer.Option(100, "--fix-every", help="a checkpoint every this many steps (0: none)"),
    json_out: bool = typer.Option(False, "--json", help="print the figures as JSON"),
    seed: int = typer.Option(0, "--seed", help="random seed of the synthetic walk"),
):
    """Cost per step of the gtsam fusion over a long synthetic incident (flat if marginalisation works)."""
    report = bench_fusion(steps=steps, fix_every=fix_every, seed=seed)
    if json_out:
        print_json(report)
        return
    for key, value in report.items():
        out.print(f"{key:>22}  {value:.4g}" if isinstance(value, float) else f"{key:>22}  {value}", highlight=False)

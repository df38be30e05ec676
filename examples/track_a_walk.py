"""Track one IPIN walk with the PDR alone and plot it against the walk's surveyed landmarks.

    python examples/track_a_walk.py [WALK] [--out track.png]

WALK is an IPIN 2023 GetSensorData log (default: the first development walk in
../shared/data/ipin2023). The pipeline turns IMU samples into steps, each with a length L_k and
a heading ψ_k (ENU yaw, counter-clockwise from East); dead reckoning places the walker from the
first landmark on:  x_k = x_{k-1} + L_k cos ψ_k,  y_k = y_{k-1} + L_k sin ψ_k.
No fix corrects it: the distance to the landmarks is the PDR's own drift.
"""
import argparse
import math
from pathlib import Path

import matplotlib
import numpy as np
import pymap3d

from pdr.events import StepEvent
from pdr.floors import FloorElevations
from pdr.heading import HeadingSettings
from pdr.io import load
from pdr.pipeline import PdrPipeline, PipelineSettings, frames_of, run_pipeline

WALK = Path(__file__).resolve().parents[2] / "shared/data/ipin2023/IPIN2023_T3_TrainingTrial01_repetition01.txt.gz"
DECLINATION = math.radians(3.6)  # Nuremberg, east (World Magnetic Model 2023; deploy/incidents/ipin-museum.json)


def walk_steps(walk: Path):
    """The walk's steps from its first landmark on, and its landmarks in ENU metres around it."""
    rec = load(walk)
    imu, lm = rec.imu_samples(), rec.landmarks
    settings = PipelineSettings(heading=HeadingSettings(declination=DECLINATION))
    pipeline = PdrPipeline(settings, FloorElevations.uniform(3.0, -2, 0), start_floor=int(lm.floor[0]))
    pressure = (rec.pressure.t, rec.pressure.values[:, 0]) if rec.pressure is not None else (None, None)
    events = run_pipeline(pipeline, frames_of(imu.t, imu.acc, imu.gyr, imu.mag, *pressure, per_frame=10))
    steps = [e for e in events if isinstance(e, StepEvent) and e.t >= lm.t[0]]
    lx, ly, _ = pymap3d.geodetic2enu(lm.lat, lm.lon, 0.0, lm.lat[0], lm.lon[0], 0.0)
    return steps, lm.t, np.asarray(lx), np.asarray(ly)


def plot(out: Path, title: str, lx, ly, tracks: dict, checkpoints=()):
    """Tracks (label -> (x, y)) over the landmarks, numbered; ``checkpoints`` drawn filled."""
    matplotlib.use("Agg")  # a file, no window
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 7))
    for label, (x, y) in tracks.items():
        ax.plot(x, y, lw=1, label=label)
    used = np.isin(np.arange(len(lx)), checkpoints)
    ax.scatter(lx[~used], ly[~used], facecolors="none", edgecolors="k", marker="D", s=30, zorder=3, label="landmarks")
    if used.any():
        ax.scatter(lx[used], ly[used], c="k", marker="D", s=30, zorder=3, label="checkpoints")
    names: dict = {}
    for k, spot in enumerate(zip(np.round(lx, 1), np.round(ly, 1)), start=1):
        names.setdefault(spot, []).append(str(k))  # a landmark visited twice gets one label
    for (a, b), ks in names.items():
        ax.annotate(",".join(ks), (a, b), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax.set(xlabel="east (m)", ylabel="north (m)", title=title, aspect="equal")
    ax.legend()
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)


def track_a_walk(walk: Path, out: Path) -> np.ndarray:
    """One row (t, x, y, floor) per step; the plot in ``out``."""
    steps, _, lx, ly = walk_steps(walk)
    length, heading = np.array([s.length for s in steps]), np.array([s.heading for s in steps])
    x = lx[0] + np.cumsum(length * np.cos(heading))
    y = ly[0] + np.cumsum(length * np.sin(heading))
    plot(out, walk.name, lx, ly, {f"PDR, {len(steps)} steps": (np.r_[lx[0], x], np.r_[ly[0], y])})
    return np.column_stack([[s.t for s in steps], x, y, [s.floor for s in steps]])


if __name__ == "__main__":
    cli = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_argument("walk", nargs="?", type=Path, default=WALK)
    cli.add_argument("--out", type=Path, default=Path("track.png"))
    args = cli.parse_args()
    track = track_a_walk(args.walk, args.out)
    print(f"{len(track)} steps, {np.hypot(*np.diff(track[:, 1:3], axis=0).T).sum():.0f} m walked; plot in {args.out}")

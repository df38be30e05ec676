"""``firetrack bench``: benchmark commands that print JSON figures (never timed tests)."""
from __future__ import annotations

import os
import time

import numpy as np
import typer

from pdr.ahrs import FILTERS, make_filter
from pdr.ahrs.reference import scf_reference
from pdr.synthetic import rotating_imu
from service.fusion.bench import fusion_command
from service.protocol.terminal import err, print_json

app = typer.Typer(help="Benchmarks: each prints JSON figures. Without a sub-command: the live service under load.",
                  invoke_without_command=True)  # the load bench (client/load_bench.py) is the callback, set in client/cli.py


app.command("fusion")(fusion_command)


@app.command("resume")
def bench_resume_command(
    responders: int = typer.Option(4, "--responders", "-n", help="simulated walkers"),
    minutes: float = typer.Option(20.0, "--minutes", help="how long they walk before the crash"),
):
    """What a restart costs: resume from the newest snapshot against a replay of the whole recording (JSON)."""
    from service.review.resume import bench_resume

    print_json(bench_resume(responders, minutes, log=lambda m: err.print(m)))


def _cpu_seconds(fn) -> float:
    """CPU time of ``fn()`` on this thread (one core), robust to a busy shared machine."""
    t0 = time.thread_time()
    fn()
    return time.thread_time() - t0


@app.command("ahrs")
def bench_ahrs(
    seconds: float = typer.Option(3600.0, help="length of the synthetic recording, s"),
    rate: float = typer.Option(100.0, help="sample rate, Hz"),
    batch: int = typer.Option(10, help="live batch size (samples per update call)"),
    repeats: int = typer.Option(3, help="best of this many runs"),
    baseline_seconds: float = typer.Option(60.0, help="length fed to the pure-Python baseline"),
):
    """Throughput of each filter in samples/s on one core over a long synthetic recording.

    Each filter runs through its streaming ``update`` call, once as a single batch and once
    in live-sized batches; the in-process baseline is the readable pure-Python FSCF.
    """
    err.print(f"synthesising {seconds:.0f} s at {rate:.0f} Hz ...")
    imu = rotating_imu(seconds=seconds, rate_hz=rate, seed=1)
    n = len(imu.t)
    report = {"samples": n, "rate_hz": rate, "batch": batch, "cpu": os.cpu_count(), "filters": {}}
    for name in FILTERS:
        make_filter(name).update(imu.t[:50], imu.acc[:50], imu.gyr[:50], imu.mag[:50])  # compile outside the clock
        one = min(_cpu_seconds(lambda: make_filter(name).update(imu.t, imu.acc, imu.gyr, imu.mag)) for _ in range(repeats))

        def live():
            f = make_filter(name)
            for i in range(0, n, batch):
                f.update(imu.t[i:i + batch], imu.acc[i:i + batch], imu.gyr[i:i + batch], imu.mag[i:i + batch])

        m = min(n, int(600 * rate))  # live batches over at most 10 minutes of data
        t_live = min(_cpu_seconds(live) if m == n else _cpu_seconds(lambda: _live_prefix(name, imu, batch, m)) for _ in range(repeats))
        report["filters"][name] = {
            "samples_per_s": n / one,
            "samples_per_s_live_batches": m / t_live,
        }
        err.print(f"{name}: {n / one:,.0f} samples/s (one batch), {m / t_live:,.0f} samples/s (batches of {batch})")
    k = int(baseline_seconds * rate)
    dt = np.diff(imu.t[: k + 1])
    t_py = _cpu_seconds(lambda: scf_reference(imu.q_true[0], dt, imu.acc[1 : k + 1], imu.gyr[1 : k + 1], imu.mag[1 : k + 1], exact=False))
    report["baseline_python_fscf_samples_per_s"] = k / t_py
    report["fscf_speedup_vs_python"] = report["filters"]["fscf"]["samples_per_s"] / (k / t_py)
    print_json(report)


def _live_prefix(name, imu, batch, m):
    f = make_filter(name)
    for i in range(0, m, batch):
        f.update(imu.t[i:i + batch], imu.acc[i:i + batch], imu.gyr[i:i + batch], imu.mag[i:i + batch])


@app.command("zupt")
def bench_zupt(
    seconds: float = typer.Option(1800.0, help="length of the synthetic boot recording, s"),
    rate: float = typer.Option(200.0, help="IMU rate, Hz"),
    batch: int = typer.Option(10, help="live batch size (samples per update call)"),
    repeats: int = typer.Option(3, help="best of this many runs"),
):
    """Throughput (samples/s on one core, thread CPU time) of the boot INS: detector + filter
    (:class:`pdr.zupt.ZuptIns`) and the whole motion model, at once and in live batches."""
    from pdr.pipeline import ImuFrame
    from pdr.zupt import ZuptIns
    from pdr.zupt.motion_model import ZuptMotionModel
    from pdr.zupt.synthetic import foot_walk

    n_strides = max(1, int((seconds - 4.0) / 1.1))
    rng = np.random.default_rng(1)
    strides = np.column_stack((rng.uniform(0.9, 1.5, n_strides), rng.normal(0.0, 0.3, n_strides), np.zeros(n_strides)))
    err.print(f"synthesising {n_strides} strides at {rate:.0f} Hz ...")
    w = foot_walk(strides, rate_hz=rate, acc_noise=0.02, gyr_noise=float(np.radians(0.5)), seed=1)
    n = len(w.t)
    ZuptIns().update(w.t[:2000], w.acc[:2000], w.gyr[:2000])  # compile outside the clock
    m = min(n, int(600 * rate))  # live batches over at most 10 minutes of data

    def ins_once():
        f = ZuptIns()
        f.update(w.t, w.acc, w.gyr)
        f.finish()

    def ins_live():
        f = ZuptIns()
        for i in range(0, m, batch):
            f.update(w.t[i:i + batch], w.acc[i:i + batch], w.gyr[i:i + batch])

    def model_live():
        f = ZuptMotionModel()
        for i in range(0, m, batch):
            f.update(ImuFrame(w.t[i:i + batch], w.acc[i:i + batch], w.gyr[i:i + batch]))

    one = min(_cpu_seconds(ins_once) for _ in range(repeats))
    live = min(_cpu_seconds(ins_live) for _ in range(repeats))
    model = min(_cpu_seconds(model_live) for _ in range(repeats))
    report = {
        "samples": n, "rate_hz": rate, "batch": batch, "cpu": os.cpu_count(),
        "ins_detector_samples_per_s": n / one,
        "ins_detector_samples_per_s_live_batches": m / live,
        "motion_model_samples_per_s_live_batches": m / model,
        "realtime_factor_live": (m / model) / rate,
    }
    err.print(f"INS + detector: {n / one:,.0f} samples/s at once, {m / live:,.0f} in batches of {batch}; "
              f"motion model {m / model:,.0f} samples/s in batches of {batch}")
    print_json(report)


@app.command("decode")
def bench_decode(
    frames: int = typer.Option(20000, help="decodes per run"),
    runs: int = typer.Option(5, help="runs; every run is reported"),
):
    """Time to decode and validate one live frame (10 samples at 100 Hz with magnetometer and
    pressure, as a phone sends it), on the fast path (msgspec) and on the schema's own validation."""
    from service.protocol import wire
    from service.protocol.codec import _fast_imu, decode

    rng = np.random.default_rng(0)
    t = 1000.0 + np.arange(10) / 100.0
    payload = wire.encode(wire.ImuBatch(
        responder="ff1", device="phone-1", boot="b1", seq=7, t=t, acc=rng.normal(0, 1, (10, 3)) + [0, 0, 9.81],
        gyr=rng.normal(0, 0.1, (10, 3)), mag=rng.normal(0, 30, (10, 3)), pressure_t=t[:1], pressure=np.array([1013.2]),
        carry="handheld", utc_offset=1.7e9))
    if _fast_imu(payload) is None:
        raise RuntimeError("the common frame did not take the fast path")
    report = {"payload_bytes": len(payload), "frames_per_run": frames}
    for name, fast in (("fast_path_us_per_frame", True), ("schema_path_us_per_frame", False)):
        times = []
        for _ in range(runs):
            t0 = time.perf_counter()
            for _ in range(frames):
                decode(payload, expect=wire.ImuBatch, fast=fast)
            times.append(round((time.perf_counter() - t0) / frames * 1e6, 3))
        report[name] = times
    print_json(report)

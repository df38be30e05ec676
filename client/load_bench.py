"""``firetrack bench --responders N --seconds S [--rate HZ] --json``: the service under load.

N simulated wearables (:class:`client.simulate.SimulationPublisher`, in a separate process so
they do not share the service's interpreter) publish 10 frames a second each through a real
zenoh router on loopback — the service's own in-process router, as deployed by default —
with reliable, blocking congestion control. The service runs as in production. The wearers
start walking at random moments over the first ``start_spread_s`` (5 s by default; a crew does
not take its first step in the same instant — and the pipeline confirms a walk by releasing
its first four steps together, so 200 wearers starting at once make one burst of 800 graph
updates; ``--start-spread 0`` measures that worst case). Figures:

* ``samples_per_s`` — IMU samples the service processed per second of the run;
* ``realtime_factor`` — samples processed per second of the worker's busy time, over the
  samples the wearables produce per second (N·rate): above 1 the service keeps up, and by
  how much (2 = it could take twice the load);
* ``latency_p50_ms``/``latency_p99_ms`` — from a frame's publication (wall clock in the
  publisher) to the publication of the pose that reflects it, same machine. When the worker
  ran several frames of the responder through its tracker as one batch (it does when it is
  behind), the clock starts at the oldest frame of that batch, not the newest
  (``Pose.seq``), so batching cannot flatter the figure. Steady state: after each wearable's first 3 s (``latency_warmup_max_ms`` is the worst
  of those, when numba kernels compile and trackers start);
* ``frames_sent``/``frames_processed``/``frames_lost`` — lost = sent but never processed, and
  ``frames_not_processed`` says why (the gates' rejects by reason, frames declared lost, held);
* ``rss_mb`` — peak resident memory of the service process (router included).

``--foot F`` makes a share F of the wearers boot-mounted (``carry="foot"``: the ZUPT-aided INS
instead of the handheld pipeline; :class:`client.simulate.BootStreams`);
``latency_p99_ms_boot``/``latency_p99_ms_handheld`` split the latency by kind, and
``worker_cpu_ms_per_responder_s`` (the workers' busy time per responder per second) compares
what each kind costs between runs.

``--tls`` runs the same with security on: an incident CA made for the run, the service and
its workers with a service certificate, the wearables' process with a simulator certificate
(walkers ``sim-000``...), mutual TLS on every link and the router's access control generated
from the roster, as ``firetrack serve --tls`` runs it. Run it beside a run without, in the same
conditions, for the cost of security.

``--router-process`` runs the zenoh router in a process of its own (as ``zenohd`` in
``deploy/`` or a router on another box would), and worker 0 joins it as a client like the
others, so no worker shares its process with the router. ``router_cpu_s`` is that process's CPU.
"""
from __future__ import annotations

import contextlib
import cProfile
import dataclasses
import io
import math
import multiprocessing as mp
import os
import pstats
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import typer

from client.process_stats import cpu_s
from service.protocol.session import free_local_port
from service.protocol.terminal import err, leave_process, print_json
from service.shell.sharding import in_shard
from service.shell.workers import WorkerPool


def _publisher(endpoint: str, incident: str, n: int, seconds: float, rate: float, seed: int, out: str,
               ready, go, start_spread_s: float, tls_dir: str | None = None, foot: float = 0.0,
               drill: bool = False) -> None:  # pragma: no cover - child

    from client.simulate import SimulationPublisher
    from service.protocol.session import open_client
    from service.protocol.tls import TlsIdentity

    session = open_client(endpoint, tls=TlsIdentity.load(tls_dir) if tls_dir else None)
    # each wearable keeps what a real one keeps (KEEP_FRAMES, 5 min) for the service's requests (Status.missing): a
    # view of the precomputed table (client.simulate.PrecomputedKeep, no copy); zenoh's keep stays SIM_KEEP_FRAMES
    pub = SimulationPublisher(session, incident, n, rate, seed, truth=False, start_spread_s=start_spread_s, foot=foot,
                              drill=drill)
    frames = int(seconds * 10) + 20
    send_t = np.full((n, frames), np.nan)

    def on_frame(i, seq, t):
        if seq < frames:
            send_t[i, seq] = t

    pub.step(1)  # the first (door) fixes and one frame: declarations settle before timing starts
    payloads = pub.precompute(seconds)  # simulated and encoded before the clock starts: a put per frame
    ready.set()
    go.wait(60)
    cpu0 = time.process_time()
    sent = 1 + pub.run_precomputed(payloads, on_frame=on_frame) // max(n, 1)
    np.savez(out, send_t=send_t, frames_per_walker=sent, cpu=time.process_time() - cpu0)
    pub.close()
    session.close()
    leave_process(0)  # a thousand wearables' zenoh threads must not outlive the interpreter


PUBLISHER_STALL_S = 60.0  # s the publisher may go on while the service processes no frame at all


def _router(endpoint: str, tls_dir: str | None, acl: dict | None, ready, stop) -> None:  # pragma: no cover - child
    """A zenoh router alone in its process until ``stop`` is set (``--router-process``)."""
    from service.protocol.session import open_session
    from service.protocol.tls import TlsIdentity

    session = open_session([endpoint], tls=TlsIdentity.load(tls_dir) if tls_dir else None, acl=acl)
    ready.set()
    stop.wait()
    session.close()
    leave_process(0)


def _wait_publisher(child, svc, seconds: float) -> None:
    """Until the publisher has sent its frames. A service behind pushes back (blocking
    congestion control), so the publisher takes longer than ``seconds`` then: that is the
    overload being measured, not a failure, as long as the service keeps processing frames."""
    deadline = time.monotonic() + seconds + 120.0
    seen, since = svc.frames_processed, time.monotonic()
    while child.is_alive():
        child.join(1.0)
        if svc.frames_processed != seen:
            seen, since = svc.frames_processed, time.monotonic()
        if time.monotonic() > deadline and time.monotonic() - since > PUBLISHER_STALL_S:
            break
    if child.exitcode != 0:
        raise RuntimeError(f"the publisher process failed (exit code {child.exitcode})")


DRILL_CONFIRM_S = 3.0  # s: four steps at 1.8 Hz and the ramp up to speed
EVEN_MIN_SPAN_S = 5.0  # s of poses a responder needs in the window to have rates


def _even(poses, names, lo: float, hi: float, workers: int, seq_from: int = 0) -> dict:
    """How evenly the responders were tracked between wall times ``lo`` and ``hi``: per
    responder, from its first pose to its last there, poses per second and frames its track
    advanced per second (the seq its poses reflect; 10 keeps up with a wearable); min, median,
    max of each and the largest deviation from the median, relative. Responders whose poses
    there span less than ``EVEN_MIN_SPAN_S`` are left out (and counted out).

    Only poses of frames from ``seq_from`` on count: the frames in which every wearer walks
    (:func:`_even_from`). A service behind publishes at wall time ``lo`` the poses of frames
    sent seconds before it, while some of a drill crew still stood or had just started:
    their first steps, released four at once when the walk is confirmed, were then counted as
    if at the service's pace (issue 29, N = 1050 drill: 15 s behind at the end)."""
    rate, progress, shard = [], [], []
    by: dict[str, list] = {}
    for rid, seq, pub in poses:
        if lo <= pub <= hi and seq >= seq_from:
            by.setdefault(rid, []).append((pub, seq))
    for rid in names:
        mine = by.get(rid, [])
        span = mine[-1][0] - mine[0][0] if len(mine) >= 2 else 0.0
        if span >= EVEN_MIN_SPAN_S:  # from its first pose to its last
            rate.append((len(mine) - 1) / span)
            progress.append((mine[-1][1] - mine[0][1]) / span)
            shard.append(next(k for k in range(workers) if in_shard(rid, k, workers)))
    out: dict = {"responders": len(rate)}
    if not rate:
        return out
    # the median frames/s of each worker's responders: a worker slower than another is uneven too
    # (None: none of its responders had poses over EVEN_MIN_SPAN_S, a worker too far behind)
    by_worker = [[p for p, k in zip(progress, shard) if k == w] for w in range(workers)]
    out["frames_per_s_by_worker"] = [round(float(np.median(ps)), 3) if ps else None for ps in by_worker]
    out["responders_by_worker"] = [len(ps) for ps in by_worker]
    for name, xs in (("poses_per_s", rate), ("frames_per_s", progress)):
        xs = np.array(xs)
        mid = float(np.median(xs)) if xs.size else 0.0
        out[name] = {"min": round(float(xs.min()), 3), "median": round(mid, 3), "max": round(float(xs.max()), 3),
                     "spread": round(float(np.abs(xs - mid).max() / mid), 3) if mid > 0 else None}
    return out


def _even_from(drill: bool, start_spread_s: float) -> float:
    """s after the start from which ``tracked_evenly`` counts: after the first 3 s; for a drill
    crew, once the last wearer has waited (``start_spread_s``), stood (``initial_still_s``) and
    taken the four steps that confirm a walk (:data:`DRILL_CONFIRM_S`), so each is walking throughout."""
    if not drill:
        return WARMUP_FRAMES / 10.0
    from pdr.simulation import WalkerSettings

    return max(WARMUP_FRAMES / 10.0, start_spread_s + WalkerSettings().initial_still_s + DRILL_CONFIRM_S)


def _p99(ms: np.ndarray) -> float | None:
    return float(np.percentile(ms, 99)) if ms.size else None


def _summed(dicts) -> dict[str, int]:
    out: dict[str, int] = {}
    for d in dicts:
        for k, v in d.items():
            out[k] = out.get(k, 0) + v
    return out


START_WAIT_S = 120.0  # s the publisher may take to connect and precompute its frames, plus
START_WAIT_PER_WALKER_S = 0.3  # s per walker (a 30 s run of 1000 walkers: ~100 s on a loaded 2-core machine)
WARMUP_FRAMES = 30  # the first 3 s of each wearable: kernels compile, trackers and graphs are built

# Where the worker's time goes, by stage: (file, function) pairs whose cumulative time the
# profile sums over the PDR engine's rounds (pdr/fleet*, a fleet of one alike).
STAGES: dict[str, tuple[tuple[str, str], ...]] = {
    "zenoh take": (("service/shell/round_intake.py", "take_frames"), ("service/shell/round_intake.py", "take_queued")),
    "decode": (("service/protocol/codec.py", "decode"),),
    "frame gate": (("service/core/gate.py", "offer"), ("service/core/gate.py", "expire")),
    "heading (AHRS, bias, compass, per step)": (
        ("pdr/fleet_kernels.py", "heading_stage"), ("pdr/heading.py", "take_epochs"), ("pdr/heading.py", "answer_steps")),
    "height and floors": (("pdr/fleet.py", "_height_round"),),
    "step detection": (("pdr/detector_kernels.py", "detector_buffer"), ("pdr/detector_kernels.py", "detector_stage"),
                       ("pdr/fleet.py", "_design")),
    "step length, stairs, floor events": (("pdr/step_events.py", "assemble"), ("pdr/step_events.py", "release")),
    "motion state": (("pdr/fleet_kernels.py", "motion_windows"), ("pdr/fleet_kernels.py", "motion_grid")),
    "pipeline (all stages)": (("pdr/fleet.py", "run"), ("pdr/fleet.py", "finish")),
    "fusion (graph, dead reckoning)": (("service/fusion/estimators.py", "add_step"), ("service/fusion/estimators.py", "add_fix"),
                                       ("service/fusion/estimators.py", "set_floor"), ("service/fusion/estimators.py", "flush")),
    "pose message": (("service/core/pose_output.py", "_emit_poses"), ("service/core/pose_output.py", "pose_message")),
    "status": (("service/core/incident_core.py", "status_of"),),
    "publish (encode, put)": (("service/shell/service.py", "_publish"),),
    "worker total": (("service/shell/service.py", "_run_round"), ("service/shell/round_intake.py", "take_frames"),
                     ("service/shell/round_intake.py", "take_queued")),
}


IDLE_STAGES = ("zenoh take", "worker total")  # they contain the worker's wait for input, taken out


def stage_table(stats: pstats.Stats, frames: int, steps: int) -> dict[str, dict[str, float]]:
    """µs per frame and per step of each stage in :data:`STAGES` (cumulative profile times, which
    cProfile inflates for Python-heavy code more than for compiled kernels). The time the worker
    spent blocked in ``queue.get`` waiting for input (idle, not work) is taken out of
    :data:`IDLE_STAGES` and shown as its own row."""
    totals = {k: 0.0 for k in STAGES}
    idle = 0.0
    for (path, _, func), (_, _, _, cum, callers) in stats.stats.items():
        path = path.replace("\\", "/")
        for stage, entries in STAGES.items():
            if any(path.endswith(f) and func == fn for f, fn in entries):
                totals[stage] += cum
        if path.endswith("queue.py") and func == "get":
            idle += sum(c[3] for (cpath, _, cfunc), c in callers.items()
                        if cpath.replace("\\", "/").endswith("service/shell/round_intake.py") and cfunc == "take_queued")
    for k in IDLE_STAGES:
        totals[k] -= idle
    totals["idle (waiting for input)"] = idle
    return {k: {"us_per_frame": round(1e6 * v / max(frames, 1), 1), "us_per_step": round(1e6 * v / max(steps, 1), 1)}
            for k, v in totals.items()}


def _bench_pki(directory: Path, incident: str):
    """An incident CA for one run: the service, and the simulator the wearables publish as."""
    from service.protocol import pki
    from service.protocol.access import load_roster
    from service.protocol.tls import TlsIdentity

    pki.init_ca(directory, incident)
    svc = TlsIdentity.load(pki.issue(directory, "service", "svc").dir)
    sim = TlsIdentity.load(pki.issue(directory, "simulator", "sim").dir)
    return svc, sim, load_roster(directory / "roster.json")


def bench_service(responders: int = 200, seconds: float = 30.0, rate: float = 100.0, seed: int = 0,
                  profile: Path | None = None, drain_s: float = 30.0, log=print, workers: int = 2,
                  start_spread_s: float = 5.0, tls: bool = False, foot: float = 0.0, drill: bool = False,
                  router_process: bool = False) -> dict:

    from service.protocol.incident import default_incident
    from service.protocol.session import open_session
    from service.shell.service import IncidentService, ServiceSettings

    endpoint = f"{'tls' if tls else 'tcp'}/127.0.0.1:{free_local_port()}"
    cfg = default_incident()
    poses: list[tuple[str, int, float]] = []
    prof = cProfile.Profile() if profile is not None else None
    share0 = sum(in_shard(f"sim-{i:03d}", 0, workers) for i in range(responders))
    with contextlib.ExitStack() as done:  # whatever fails, the processes, threads and sessions end
        stats_dir = done.enter_context(tempfile.TemporaryDirectory(prefix="firetrack-bench-"))
        svc_id = sim_id = access = None
        acl = None
        if tls:
            from service.protocol.access import access_control, access_message

            svc_id, sim_id, roster = _bench_pki(Path(stats_dir) / "pki", cfg.id)
            acl, access = access_control(roster, cfg.id), access_message(roster)
        ctx = mp.get_context("spawn")
        router = None
        if router_process:  # the router alone; worker 0 a client of it, like the pool's workers
            r_ready, r_stop = ctx.Event(), ctx.Event()
            router = ctx.Process(target=_router, args=(endpoint, str(svc_id.dir) if tls else None, acl, r_ready, r_stop))
            router.start()
            done.callback(lambda: router.kill() if router.is_alive() else None)
            done.callback(lambda: (r_stop.set(), router.join(10.0)))
            if not r_ready.wait(60.0):
                raise RuntimeError(f"the router process did not start within 60 s (exit code {router.exitcode})")
            session = open_session(None, endpoint, tls=svc_id)
        else:
            session = open_session([endpoint], tls=svc_id, acl=acl)
        done.callback(session.close)
        # the crew is known: admit all of it at once, as `serve --admit-burst N` (or a roster) would at an incident
        # of that size (the default budget, 256 new ids at once then 2/s, is for an unknown crowd)
        base = ServiceSettings()
        settings = dataclasses.replace(base, core=dataclasses.replace(base.core, intake=dataclasses.replace(
            base.core.intake, admit_burst=max(base.core.intake.admit_burst, responders),
            max_responders=max(base.core.intake.max_responders, responders))))
        svc = IncidentService(session, cfg, settings, shard=(0, workers), access=access,
                              actor=svc_id.name if svc_id else "service")
        svc.pose_hook = lambda rid, msg, oldest: poses.append((rid, oldest, msg.published_at))
        svc.profiler = prof
        done.callback(svc.close)
        svc.start()
        pool = WorkerPool(endpoint, cfg, workers, stats_dir, log_poses=True, settings=settings,
                          tls_dir=str(svc_id.dir) if tls else None,
                          roster=str(Path(stats_dir) / "pki" / "roster.json") if tls else None)
        done.callback(pool.close)
        if not pool.wait_ready(120):
            raise RuntimeError("the service workers did not start within 120 s")
        ready, go = ctx.Event(), ctx.Event()
        out = str(Path(stats_dir) / "sent.npz")
        child = ctx.Process(target=_publisher, args=(endpoint, cfg.id, responders, seconds, rate, seed, out, ready, go,
                                                     start_spread_s, str(sim_id.dir) if tls else None, foot, drill))
        child.start()
        done.callback(lambda: child.kill() if child.is_alive() else None)
        # the publisher simulates and encodes every frame before the clock starts: on a busy machine
        # a thousand walkers take minutes, so wait while it is alive and working, up to a bound
        start_wait = START_WAIT_S + START_WAIT_PER_WALKER_S * responders
        waited = time.monotonic()
        while not ready.wait(1.0):
            if not child.is_alive():
                raise RuntimeError(f"the publisher process failed while starting (exit code {child.exitcode})")
            if time.monotonic() - waited > start_wait:
                raise RuntimeError(f"the simulated wearables did not start within {start_wait:.0f} s")
        log(f"{responders} wearables connected; running {seconds:g} s at {rate:g} Hz ...")
        busy0, frames0, t0 = svc.busy_s, svc.frames_processed, time.monotonic()
        calls0 = svc.tracker_batches
        go_wall = time.time()
        go.set()
        _wait_publisher(child, svc, seconds)
        end_wall = time.time()
        sent = np.load(out)
        send_t, per_walker, publisher_cpu = sent["send_t"], int(sent["frames_per_walker"]), float(sent["cpu"])
        frames_sent = per_walker * responders
        # the backlog drains for as long as it shrinks: a worker far behind (tens of seconds) is
        # waited for; one that made no progress for drain_s is given up on, its frames then lost
        seen, moved = svc.frames_processed, time.monotonic()
        while svc.frames_processed < per_walker * share0 and time.monotonic() - moved < drain_s:
            time.sleep(0.05)
            if svc.frames_processed != seen:
                seen, moved = svc.frames_processed, time.monotonic()
        svc.wait_idle(5.0)
        svc_frames = svc.frames_processed
        svc_steps = sum(r.tracker.steps for r in list(svc.responders.values()))
        others = pool.close(timeout=drain_s)  # a loaded worker drains its backlog (worker 0 has drained by now)
        router_cpu = cpu_s(router.pid) if router is not None else math.nan
        wall = time.monotonic() - t0
        accounting = [svc.frame_accounting()] + [s.get("frames_not_processed", {}) for s in others]
    per_sample = rate / 10.0
    # counts from the start (the first frame of each wearable went out before the timed run);
    # capacity from what was processed while the worker's busy time was being counted
    shards = [{"frames_processed": svc.frames_processed, "frames_timed": svc.frames_processed - frames0,
               "busy_s": svc.busy_s - busy0, "responders": share0,
               "tracker_batches": svc.tracker_batches - calls0}] + others
    processed = sum(s["frames_processed"] for s in shards)
    samples = sum(s.get("frames_timed", s["frames_processed"]) for s in shards) * per_sample
    capacity = [(s.get("frames_timed", s["frames_processed"]) * per_sample / s["busy_s"]) / (s["responders"] * rate)
                for s in shards if s["busy_s"] > 0 and s["responders"]]
    for s in others:
        poses += [tuple(p) for p in s["poses"]]
    lat, warm, when, boot = [], [], [], []
    index = {f"sim-{i:03d}": i for i in range(responders)}
    boots = int(round(foot * responders))  # the first ones wear the IMU on the boot (client.simulate.BootStreams)
    for rid, seq, pub in poses:
        i = index.get(rid)
        if i is not None and seq < send_t.shape[1] and np.isfinite(send_t[i, seq]):
            (warm if seq < WARMUP_FRAMES else lat).append(pub - send_t[i, seq])
            if seq >= WARMUP_FRAMES:
                when.append(seq)
                boot.append(i < boots)
    lat = np.array(lat) * 1e3
    boot = np.array(boot, dtype=bool)
    warm = np.array(warm) * 1e3
    when = np.array(when) // 50  # 5 s windows of the run (frames at 10 per second)
    by_window = [round(float(np.percentile(lat[when == w], 99)), 1) for w in np.unique(when)] if lat.size else []
    even_from = _even_from(drill, start_spread_s)  # s after the start from which every wearer walks
    result = {
        "responders": responders,
        "tls": tls,
        "rate_hz": rate,
        "seconds": seconds,
        "start_spread_s": start_spread_s,
        "drill": drill,
        "samples_per_s": samples / wall,
        "realtime_factor": min(capacity) if capacity else None,
        "latency_p50_ms": float(np.percentile(lat, 50)) if lat.size else None,
        "latency_p99_ms": float(np.percentile(lat, 99)) if lat.size else None,
        "latency_warmup_max_ms": float(warm.max()) if warm.size else None,
        "latency_p99_ms_per_5s": by_window,
        "boot_wearers": boots,
        "latency_p99_ms_boot": _p99(lat[boot]) if boots else None,
        "latency_p99_ms_handheld": _p99(lat[~boot]) if boots < responders else None,
        "worker_cpu_ms_per_responder_s": round(1e3 * sum(s["busy_s"] for s in shards) / (responders * wall), 3),
        "frames_sent": frames_sent,
        "frames_processed": processed,
        "frames_lost": frames_sent - processed,
        "frames_not_processed": _summed(accounting),
        "poses": len(poses),
        "workers": workers,
        "frames_per_tracker_batch": round(sum(s.get("frames_timed", s["frames_processed"]) for s in shards)
                                          / max(sum(s["tracker_batches"] for s in shards), 1), 2),
        "worker_busy_fraction": [round(s["busy_s"] / wall, 3) for s in shards],
        "behind_max_s": max([svc.behind_max_s] + [s.get("behind_max_s", 0.0) for s in others]),  # service.core.lag
        "behind_max_s_by_worker": [round(x, 2) for x in [svc.behind_max_s] + [s.get("behind_max_s", 0.0) for s in others]],
        "publishing_s": round(end_wall - go_wall, 1),  # longer than seconds: the service pushed back
        # per responder while the wearables published (after the first 3 s): poses/s and frames/s its track advanced
        "tracked_evenly": _even(poses, list(index), go_wall + even_from, end_wall, workers,
                                seq_from=int(math.ceil(10.0 * even_from))),
        "publisher_cpu_s": publisher_cpu,
        "router_process": router_process,
        # the router's own process (--router-process); null when it is in worker 0's (or /proc cannot say)
        "router_cpu_s": None if math.isnan(router_cpu) else router_cpu,
        "load_average": [round(x, 2) for x in os.getloadavg()],  # 1, 5, 15 min at the end: a shared machine's load
        "rss_mb": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                   + resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss) / 1024.0,
    }
    if prof is not None:
        buf = io.StringIO()
        stats = pstats.Stats(prof, stream=buf)
        table = stage_table(stats, svc_frames, svc_steps)
        buf.write(f"per stage, worker 0 ({svc_frames} frames, {svc_steps} steps; cProfile times)\n")
        buf.write(f"{'stage':40s} {'us/frame':>10s} {'us/step':>10s}\n")
        for k, v in table.items():
            buf.write(f"{k:40s} {v['us_per_frame']:10.1f} {v['us_per_step']:10.1f}\n")
        buf.write("\n")
        stats.sort_stats("cumulative").print_stats(30)
        Path(profile).write_text(buf.getvalue())
        prof.dump_stats(str(profile) + ".pstats")
        result["profile"] = str(profile)
        result["stages"] = table
    return result


def bench_service_command(
    ctx: typer.Context,
    responders: int = typer.Option(200, "--responders", "-n", help="simulated wearables"),
    seconds: float = typer.Option(30.0, "--seconds", help="length of the run, s"),
    rate: float = typer.Option(100.0, "--rate", help="IMU rate of each wearable, Hz"),
    as_json: bool = typer.Option(False, "--json", help="print JSON only"),
    profile: Path = typer.Option(None, "--profile", help="profile the service's worker; write the top functions here"),
    workers: int = typer.Option(2, "--workers", help="service worker processes (one per core)"),
    start_spread: float = typer.Option(5.0, "--start-spread",
                                       help="s over which the wearers start walking (0: all in the same instant)"),
    tls: bool = typer.Option(False, "--tls", help="mutual TLS on every link and the roster's access control on the "
                                                  "router (a CA made for the run)"),
    drill: bool = typer.Option(False, "--drill", help="a drill crew: every wearer keeps walking at one cadence "
                                                      "(no pauses or stairs), so tracked_evenly's pose rates compare"),
    foot: float = typer.Option(0.0, "--foot", min=0.0, max=1.0,
                               help="share of wearers with a boot-mounted IMU (ZUPT-aided INS), 0..1; the rest handheld"),
    router_process: bool = typer.Option(False, "--router-process",
                                        help="the zenoh router in a process of its own, worker 0 a client of it "
                                             "(default: the router inside worker 0's process, as serve runs it)"),
):
    """N simulated wearables through a real zenoh router against the service (see client/load_bench.py)."""
    if ctx.invoked_subcommand is not None:
        return
    try:
        result = bench_service(responders, seconds, rate, profile=profile, log=lambda m: err.print(m),
                               workers=workers, start_spread_s=start_spread, tls=tls, foot=foot, drill=drill,
                               router_process=router_process)
    except RuntimeError as e:  # a process that did not start or failed: one line, not a traceback
        err.print(f"[bold red]error:[/] {e}", highlight=False)
        raise typer.Exit(1) from None
    print_json(result)

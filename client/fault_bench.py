"""``firetrack bench faults``: the service under a flood and a storm of new ids, in figures (JSON).

The service runs as ``firetrack serve`` in its own process (its memory and log are its own);
an honest and a bystander wearable walk (simulated walkers, :class:`WalkerWearable`); an
attacker process publishes hostile messages (:func:`hostile_messages`). Three phases of
``phase_s`` each: before (the baseline of the same session), during the attack, after. Figures:

* the bystanders' pose rate and the p99 of their latency (pose received here minus the frame's
  send time; and the service's part: the pose's ``published_at`` minus the send time), pooled
  over ``--bystanders`` walkers, in each phase, and the ratios during/before;
* the service's RSS (``/proc/PID/status``) before, at its peak and after; its log's growth;
* what the service refused and why (its Status of the flooded responder; the log's summaries);
* ``--ids N``: N fresh responder ids instead of the flood: how many were admitted, the
  status messages per second, memory, and how many left by ``--expire-after``;
* the in-process cost of a hostile message (intake and core, µs per message) over the mix.

The faults themselves (a link that can be cut, walker wearables, hostile messages) are
:mod:`client.faults_loopback`'s.
"""
from __future__ import annotations

import os
import select
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import typer
import zenoh

from client.faults_loopback import (
    WalkerWearable,
    fresh_id_messages,
    hostile_messages,
    walker_frames,
)
from client.process_stats import cpu_s, rss_mb
from service.protocol import wire
from service.protocol.session import client_config, free_local_port
from service.protocol.terminal import err, print_json


# ------------------------------------------------------------------------------------------
# The benchmark
# ------------------------------------------------------------------------------------------
def _attacker(endpoint: str, incident: str, mode: str, n: int, seconds: float) -> None:  # pragma: no cover - child
    session = zenoh.open(client_config(endpoint))
    msgs = fresh_id_messages(n, incident) if mode == "ids" else hostile_messages(n, incident, "honest")
    print("ready", flush=True)
    while sys.stdin.readline().strip() == "go":  # one attack per "go" (the same messages each time)
        t0 = time.monotonic()
        for i, (key, payload) in enumerate(msgs):
            session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
            if i % 100 == 99:
                time.sleep(max(0.0, t0 + (i + 1) * seconds / n - time.monotonic()))
        time.sleep(max(0.0, t0 + seconds - time.monotonic()))  # the attack lasts its time (0 messages: a control run)
        print(f"sent {len(msgs)} {time.monotonic() - t0:.2f}", flush=True)
    session.close()


def _line_or_none(stream, timeout: float) -> str | None:
    """A line from a child's pipe if one comes within ``timeout`` s."""
    ready, _, _ = select.select([stream], [], [], timeout)
    return stream.readline().strip() if ready else None


DURING_SAMPLES = "_during_samples"  # a run's raw (latency, service latency) pairs in its attack window


def _percentile(values, q) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


class _Poses:
    """The bystander's poses as received here, with their latency from the frame's send."""

    def __init__(self, session, incident: str, walkers: dict[str, WalkerWearable]):
        self.walkers = walkers
        self.rows: list[tuple[str, float, float, float]] = []  # (responder, received, latency s, service latency s)
        self.status: dict[str, wire.Status] = {}
        self.status_times: list[float] = []
        self._lock = threading.Lock()
        self._subs = [session.declare_subscriber(wire.key_all(incident, "pose"), self._pose),
                      session.declare_subscriber(wire.key_all(incident, "status"), self._status)]

    def _pose(self, sample) -> None:
        now = time.time()
        p = wire.decode(sample.payload.to_bytes(), expect=wire.Pose)
        w = self.walkers.get(p.responder)
        if w is not None and p.seq in w.sent_at:
            with self._lock:
                self.rows.append((p.responder, now, now - w.sent_at[p.seq], p.published_at - w.sent_at[p.seq]))

    def _status(self, sample) -> None:
        st = wire.decode(sample.payload.to_bytes(), expect=wire.Status)
        with self._lock:
            self.status[st.responder] = st
            self.status_times.append(time.time())

    def phase(self, responders: list[str], t0: float, t1: float) -> dict:
        """Pose rate per responder (poses/s) and latency percentiles, pooled over ``responders``."""
        with self._lock:
            rows = [r for r in self.rows if r[0] in responders and t0 <= r[1] < t1]
        lat, svc = [r[2] for r in rows], [r[3] for r in rows]
        return {"poses_per_s": round(len(lat) / (t1 - t0) / len(responders), 3),
                "latency_p50_ms": _ms(_percentile(lat, 50)), "latency_p99_ms": _ms(_percentile(lat, 99)),
                "service_latency_p50_ms": _ms(_percentile(svc, 50)),
                "service_latency_p99_ms": _ms(_percentile(svc, 99)), "poses": len(lat)}

    def latencies(self, responders: list[str], t0: float, t1: float) -> list[tuple[float, float]]:
        """Every pose's (latency s, service latency s) in ``[t0, t1)``: for pooling runs."""
        with self._lock:
            return [(r[2], r[3]) for r in self.rows if r[0] in responders and t0 <= r[1] < t1]

    def worst(self, responders: list[str], t0: float, t1: float, n: int = 5) -> list[list]:
        """The ``n`` slowest poses in ``[t0, t1)``: ``[s since t0, latency ms, service latency ms,
        responder]``, slowest first (a transient at the attack's start shows as small first numbers)."""
        with self._lock:
            rows = sorted((r for r in self.rows if r[0] in responders and t0 <= r[1] < t1), key=lambda r: -r[2])[:n]
        return [[round(r[1] - t0, 2), _ms(r[2]), _ms(r[3]), r[0]] for r in rows]

    def timeline(self, responders: list[str], t0: float, t1: float, step: float = 10.0) -> list[list]:
        """``[s since t0, latency p50 ms, p99 ms, service latency p50 ms]`` per ``step`` s: how the
        latency moves through the run (with and without an attack)."""
        out, t = [], t0
        while t < t1:
            ph = self.phase(responders, t, min(t + step, t1))
            out.append([round(t - t0), ph["latency_p50_ms"], ph["latency_p99_ms"], ph["service_latency_p50_ms"]])
            t += step
        return out

    def status_rate(self, t0: float, t1: float) -> float:
        with self._lock:
            return round(sum(1 for t in self.status_times if t0 <= t < t1) / (t1 - t0), 1)

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


def _ms(v):
    return None if v is None else round(v * 1e3, 1)


def bench_faults(mode: str = "flood", messages: int = 100_000, attack_s: float = 30.0, phase_s: float = 30.0,
                 expire_after: float = 60.0, bystanders: int = 4, log=print, n_attacks: int = 1,
                 settle_s: float = 10.0) -> dict:
    from service.protocol.incident import default_incident

    cfg = default_incident()
    ep = f"tcp/127.0.0.1:{free_local_port()}"
    with tempfile.TemporaryDirectory(prefix="firetrack-faults-") as tmp:
        logpath = Path(tmp) / "serve.log"
        logf = open(logpath, "w")
        serve = subprocess.Popen([sys.executable, "-m", "client.entry", "serve", "--listen", ep, "--no-console",
                                  "--record", str(Path(tmp) / "incident.mcap"), "--expire-after", str(expire_after)],
                                 stdout=logf, stderr=logf)
        walkers: dict[str, WalkerWearable] = {}
        attacker = None
        session = None
        try:
            deadline = time.monotonic() + 60
            while True:
                try:
                    session = zenoh.open(client_config(ep))
                    break
                except Exception:
                    if time.monotonic() > deadline or serve.poll() is not None:
                        raise RuntimeError(f"the service did not start: {logpath.read_text()[-2000:]}")
                    time.sleep(0.3)
            time.sleep(3.0)  # warm-up and subscriptions
            total = phase_s + n_attacks * (attack_s + max(phase_s, expire_after + settle_s)) + 30.0
            names = ["honest"] + [f"bystander{j}" for j in range(bystanders)]
            for i, r in enumerate(names):
                walkers[r] = WalkerWearable(ep, cfg.id, r, walker_frames(r, total, seed=i + 1))
            poses = _Poses(session, cfg.id, walkers)
            # the attacker is another machine at an incident; here it shares this one's cores, so it
            # runs at the lowest priority, not to take the service's CPU time (what is measured)
            attacker = subprocess.Popen(["nice", "-n", "19", sys.executable, "-m", "client.fault_bench", "attacker", ep,
                                         cfg.id, mode, str(messages), str(attack_s)], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, text=True)
            if attacker.stdout.readline().strip() != "ready":
                raise RuntimeError("the attacker process did not start")
            for w in walkers.values():
                w.start()
            time.sleep(5.0)  # the walkers' first frames: trackers built
            log(f"phase 1: {phase_s:.0f} s without an attack ...")
            t_before, cpu_before = time.time(), cpu_s(serve.pid)
            time.sleep(phase_s)
            cpu_attack = cpu_s(serve.pid)
            rss_before = rss_mb(serve.pid)
            anon_before = rss_mb(serve.pid, "RssAnon")
            attacks = []  # per attack: (start, end, attacker's line, log growth, rss and anon kept after expiry)
            peak, anon_peak = rss_before, anon_before
            for k in range(n_attacks):
                log(f"phase 2: {mode}: {messages} messages in {attack_s:.0f} s" + (f" (attack {k + 1})" if k else "") + " ...")
                log0 = logpath.stat().st_size
                t_attack = time.time()
                attacker.stdin.write("go\n")
                attacker.stdin.flush()
                sent_line = ""
                while not sent_line:  # the attacker says when it is done
                    peak = max(peak, rss_mb(serve.pid))
                    anon_peak = max(anon_peak, rss_mb(serve.pid, "RssAnon"))
                    sent_line = _line_or_none(attacker.stdout, 0.25) or ""
                    if not sent_line and attacker.poll() is not None:
                        raise RuntimeError(f"the attacker process ended (exit code {attacker.returncode}) "
                                           f"during attack {k + 1}")
                t_attack_end = time.time()
                if k == 0:
                    cpu_attack_end = cpu_s(serve.pid)
                log_attack = logpath.stat().st_size - log0
                log(f"phase 3: {phase_s:.0f} s after, and until the ids the attack brought have left ...")
                t_after0 = time.time()
                rss_samples, anon_samples = [], []
                while time.time() < t_after0 + max(phase_s, expire_after + settle_s):
                    rss_samples.append(rss_mb(serve.pid))
                    anon_samples.append(rss_mb(serve.pid, "RssAnon"))
                    peak = max(peak, rss_samples[-1])
                    anon_peak = max(anon_peak, anon_samples[-1])
                    time.sleep(0.5)
                attacks.append((t_attack, t_attack_end, sent_line, log_attack, rss_samples[-1], anon_samples[-1]))
            attacker.stdin.close()
            t_after1 = time.time()
            t_attack, t_attack_end, sent_line, log_growth, rss_after, anon_after = attacks[0]
            t_after0 = t_attack_end
            by = names[1:]
            before = poses.phase(by, t_before, t_before + phase_s)
            during = poses.phase(by, t_attack, t_attack_end)
            after = poses.phase(by, t_after0, t_after0 + phase_s)
            honest = poses.status.get("honest")
            result = {
                "mode": mode, "messages": messages, "attack_s": round(t_attack_end - t_attack, 2), "attacker": sent_line,
                "bystanders": {"count": len(by), "before": before, "during": during, "after": after},
                "pose_rate_during_over_before": _ratio(during["poses_per_s"], before["poses_per_s"]),
                "latency_p99_during_over_before": _ratio(during["latency_p99_ms"], before["latency_p99_ms"]),
                "service_latency_p99_during_over_before": _ratio(during["service_latency_p99_ms"],
                                                                 before["service_latency_p99_ms"]),
                "rss_mb": {"before": round(rss_before, 1), "peak": round(peak, 1), "after": round(rss_after, 1)},
                "rss_growth_mb": round(peak - rss_before, 1),
                "rss_kept_after_mb": round(rss_after - rss_before, 1),
                "anon_mb": {"before": round(anon_before, 1), "peak": round(anon_peak, 1), "after": round(anon_after, 1)},
                "anon_growth_mb": round(anon_peak - anon_before, 1),
                "anon_kept_after_mb": round(anon_after - anon_before, 1),
                "log_growth_bytes": log_growth,
                "service_cpu_per_s": {"before": round((cpu_attack - cpu_before) / phase_s, 3),
                                      "during": round((cpu_attack_end - cpu_attack) / (t_attack_end - t_attack), 3)},
                "attacks": [{"attacker": a[2], "log_growth_bytes": a[3], "rss_kept_after_mb": round(a[4] - rss_before, 1),
                             "anon_kept_after_mb": round(a[5] - anon_before, 1)} for a in attacks],
                "status_per_s": {"before": poses.status_rate(t_before, t_attack),
                                 "during": poses.status_rate(t_attack, t_attack_end),
                                 "end_of_after": poses.status_rate(t_after1 - 5.0, t_after1)},
                "honest_status": None if honest is None else {"alarms": honest.alarms, "rejected": honest.rejected,
                                                               "lost": honest.lost},
            }
            result["latency_by_10s"] = poses.timeline(by, t_before, t_after1)
            result["slowest_during"] = poses.worst(by, t_attack, t_attack_end)
            result[DURING_SAMPLES] = poses.latencies(by, t_attack, t_attack_end)
            if mode == "ids":
                result["ids_with_a_status"] = len(poses.status) - len(names)  # admitted (each had a Status)
            poses.close()
            return result
        finally:
            for w in walkers.values():
                if w.report is None:
                    w.close(0.0)
            if attacker is not None and attacker.poll() is None:
                attacker.kill()
            if session is not None:
                session.close()
            serve.send_signal(2)
            try:
                serve.wait(30)
            except subprocess.TimeoutExpired:
                serve.kill()
            logf.close()


def against_control(result: dict, control: dict) -> dict:
    """The attack run's bystanders against a control run's (the same walkers, seeds and phases,
    no attack): the same stretch of the same walks, so what differs is the attack. The
    before-phase of the attack run itself is an earlier stretch of the walks, whose latency
    differs without any attack (``latency_by_10s``)."""
    a, c = result["bystanders"]["during"], control["bystanders"]["during"]
    return {"control": {"bystanders": control["bystanders"], "rss_kept_after_mb": control["rss_kept_after_mb"],
                        "service_cpu_per_s": control.get("service_cpu_per_s"),
                        "anon_kept_after_mb": control.get("anon_kept_after_mb"),
                        "latency_by_10s": control.get("latency_by_10s"),
                        "slowest_during": control.get("slowest_during")},
            "pose_rate_during_over_control": _ratio(a["poses_per_s"], c["poses_per_s"]),
            "latency_p99_during_over_control": _ratio(a["latency_p99_ms"], c["latency_p99_ms"]),
            "service_latency_p99_during_over_control": _ratio(a["service_latency_p99_ms"], c["service_latency_p99_ms"])}


def pooled(runs: list[dict]) -> dict:
    """The bystanders' latency over the attack windows of several runs, as one sample: a p99
    over ~200 poses is the third-slowest pose and moves by more than 20 % between two runs
    without any attack; over N runs it rests on ~2N poses."""
    samples = [x for run in runs for x in run[DURING_SAMPLES]]
    lat, svc = [x[0] for x in samples], [x[1] for x in samples]
    return {"runs": len(runs), "poses": len(samples),
            "latency_p50_ms": _ms(_percentile(lat, 50)), "latency_p99_ms": _ms(_percentile(lat, 99)),
            "service_latency_p50_ms": _ms(_percentile(svc, 50)), "service_latency_p99_ms": _ms(_percentile(svc, 99)),
            "poses_per_s": round(sum(r["bystanders"]["during"]["poses_per_s"] for r in runs) / len(runs), 3)}


def pooled_against_control(attack_runs: list[dict], control_runs: list[dict]) -> dict:
    """Pooled attack runs against pooled control runs (run alternately in one session)."""
    a, c = pooled(attack_runs), pooled(control_runs)
    return {"attack": a, "control": c,
            "pose_rate_during_over_control": _ratio(a["poses_per_s"], c["poses_per_s"]),
            "latency_p99_during_over_control": _ratio(a["latency_p99_ms"], c["latency_p99_ms"]),
            "service_latency_p99_during_over_control": _ratio(a["service_latency_p99_ms"], c["service_latency_p99_ms"])}


def _ratio(a, b):
    return None if a is None or not b else round(a / b, 3)


def reject_cost_us(messages: int = 100_000, incident=None) -> dict:
    """In-process cost of the hostile mix (:func:`hostile_messages`) through the intake and the
    core, with an honest walker's frames among them (µs per hostile message), and of each kind
    refused at the intake or rejected by the decoder (µs per message)."""
    import logging

    from service.core.incident_core import Inbound, IncidentCore
    from service.protocol.incident import default_incident

    cfg = incident or default_incident()
    msgs = hostile_messages(messages, cfg.id, "honest")
    honest = walker_frames("honest", 60.0, seed=1)
    logging.getLogger("firetrack.service").setLevel(logging.ERROR)  # the log's cost is the reject log's own
    try:
        core = IncidentCore(cfg)
        k = wire.key(cfg.id, "honest", "imu")
        core.feed_round([Inbound("imu", k, wire.encode(f), 1000.0 + i * 0.1) for i, f in enumerate(honest[:100])])
        t0 = time.perf_counter()
        now = 1010.0
        for i, (key, payload) in enumerate(msgs):
            now = 1010.0 + i * (30.0 / messages)
            kind = key.rsplit("/", 1)[1]
            if core.admit(kind, key, len(payload), now) is None:
                core.feed_round([Inbound(kind, key, payload, now)])
        per = (time.perf_counter() - t0) / messages * 1e6
        # each kind on its own, every message decoded (no budget): the decoder's price
        kinds = {}
        for c, name in enumerate(("random_bytes", "wrong_types", "nan", "duplicates_deep_oversize", "bad_fix",
                                  "long_id", "fresh_ids", "list_for_map", "random_fix", "future_version")):
            sample = msgs[c::10][:2000]
            fresh = IncidentCore(cfg)
            fresh.feed_round([Inbound("imu", k, wire.encode(f), 1000.0 + i * 0.1) for i, f in enumerate(honest[:20])])
            t0 = time.perf_counter()
            for j, (key, payload) in enumerate(sample):
                kind = key.rsplit("/", 1)[1]
                fresh.feed_round([Inbound(kind, key, payload, 1003.0 + j * 1e-4)])
            kinds[name] = round((time.perf_counter() - t0) / len(sample) * 1e6, 1)
        intake = {}
        for reason, (key, size) in {"throttled": (f"firetrack/{cfg.id}/honest/imu", 100),
                                    "bad_key": (f"firetrack/{cfg.id}/{'x' * 2000}/imu", 100),
                                    "not_admitted": (None, 100), "oversize": (f"firetrack/{cfg.id}/honest/imu", 1 << 21)}.items():
            it = IncidentCore(cfg)
            it.intake.settings = type(it.intake.settings)(max_responders=1, source_rate=1.0, source_burst=1.0)
            it.intake.admit(wire.read_key(f"firetrack/{cfg.id}/honest/imu"), 10, 0.0)
            t0 = time.perf_counter()
            for j in range(20_000):
                it.admit("imu", key or f"firetrack/{cfg.id}/n{j}/imu", size, 1.0 + j * 1e-6)
            intake[reason] = round((time.perf_counter() - t0) / 20_000 * 1e6, 2)
    finally:
        logging.getLogger("firetrack.service").setLevel(logging.NOTSET)
    return {"hostile_mix_us_per_message": round(per, 2), "refused_at_intake_us": intake,
            "decoded_and_rejected_us": kinds, "accounting": core.frame_accounting()}


def _pair_summary(run: dict) -> dict:
    """One pair of ``--pairs``: its figures against its own control, and what it kept."""
    keys = ("pose_rate_during_over_control", "latency_p99_during_over_control", "service_latency_p99_during_over_control",
            "rss_growth_mb", "rss_kept_after_mb", "log_growth_bytes", "slowest_during")
    return {"during": run["bystanders"]["during"], "control_during": run["control"]["bystanders"]["during"],
            "control_rss_kept_after_mb": run["control"]["rss_kept_after_mb"], **{k: run[k] for k in keys}}


def bench_faults_command(
    mode: str = typer.Option("flood", "--mode", help="flood: hostile messages; ids: one valid frame from each of N new ids"),
    messages: int = typer.Option(100_000, "--messages", "-n",
                                 help="messages the attacker sends (0: a control run, the same phases without an attack)"),
    attack_s: float = typer.Option(30.0, "--attack-s", help="s the attack lasts"),
    phase_s: float = typer.Option(30.0, "--phase-s", help="s of each measured phase (before, after)"),
    expire_after: float = typer.Option(60.0, "--expire-after", help="the service's --expire-after (ids mode: waits for it)"),
    bystanders: int = typer.Option(4, "--bystanders", help="bystander wearables (their figures are pooled)"),
    cost: bool = typer.Option(True, "--cost/--no-cost", help="also measure the in-process cost of the hostile mix"),
    attacks: int = typer.Option(1, "--attacks", min=1, help="attacks one after the other, each followed by its after-phase "
                                "(memory kept after each: what one leaves, the next must not add to)"),
    with_control: bool = typer.Option(False, "--control/--no-control",
                                      help="first run the same walkers and phases without an attack, and compare with it"),
    pairs: int = typer.Option(1, "--pairs", min=1, help="with --control: this many control and attack runs, "
                              "alternately, and their bystanders' latency pooled (a p99 that rests on more poses)"),
):
    """The service beside an honest and a bystander wearable under a flood (or a storm of new ids): JSON figures."""
    if mode not in ("flood", "ids"):
        err.print(f"--mode must be flood or ids, got {mode!r}")
        raise typer.Exit(2)
    def say(m):
        err.print(m)

    if pairs > 1 and not (with_control and messages > 0):
        err.print("--pairs needs --control and an attack (--messages > 0)")
        raise typer.Exit(2)
    controls, runs = [], []
    for k in range(pairs):
        tag = f" (pair {k + 1} of {pairs})" if pairs > 1 else ""
        if with_control and messages > 0:
            say(f"a control run first: the same walkers and phases, no attack{tag} ...")
            controls.append(bench_faults(mode, 0, attack_s, phase_s, expire_after, bystanders, log=say, n_attacks=attacks))
            say(f"the attack run{tag} ...")
        runs.append(bench_faults(mode, messages, attack_s, phase_s, expire_after, bystanders, log=say, n_attacks=attacks))
        if controls:
            runs[-1].update(against_control(runs[-1], controls[-1]))
    result = runs[-1] if pairs == 1 else {"pairs": [_pair_summary(r) for r in runs],
                                          "pooled": pooled_against_control(runs, controls)}
    for run in runs + controls:
        run.pop(DURING_SAMPLES, None)
    if cost and mode == "flood" and messages > 0:
        err.print("the in-process cost of the hostile mix ...")
        result["cost"] = reject_cost_us(messages)
    print_json(result)


if __name__ == "__main__":  # pragma: no cover
    if len(sys.argv) > 1 and sys.argv[1] == "attacker":
        _attacker(sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5]), float(sys.argv[6]))
    else:
        os._exit(2)

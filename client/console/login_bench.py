"""``firetrack bench logins``: what password logins cost the console, in figures (JSON).

A console with a roster of ``accounts`` operators on a loopback port, a real router behind it.
While ``concurrent`` logins run at once (each from its own loopback address, half of them
right, half wrong, again and again for ``seconds``), a reader asks ``GET /api/session`` every
``probe_every_s``: its latency percentiles say whether the hashing stalls the console (scrypt
runs off the event loop, :mod:`client.console.auth`). Then the time to answer a wrong password
for a known and for an unknown user name (medians over ``timing_trials`` interleaved trials,
fresh addresses and names so that no lock interferes): they should not tell the names apart.
"""
from __future__ import annotations

import http.client
import json
import statistics
import tempfile
import threading
import time
from pathlib import Path

import typer


def _post_login(port: int, source: str, user: str, password: str) -> tuple[int, float]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30, source_address=(source, 0))
    body = json.dumps({"user": user, "password": password})
    t0 = time.perf_counter()
    conn.request("POST", "/api/login", body=body, headers={"Host": f"127.0.0.1:{port}", "Content-Type": "application/json",
                                                           "Origin": f"http://127.0.0.1:{port}"})
    res = conn.getresponse()
    res.read()
    conn.close()
    return res.status, time.perf_counter() - t0


def _get_session(port: int) -> float:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    t0 = time.perf_counter()
    conn.request("GET", "/api/session", headers={"Host": f"127.0.0.1:{port}"})
    conn.getresponse().read()
    conn.close()
    return time.perf_counter() - t0


def _percentile(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q / 100.0 * (len(xs) - 1))))]


def roster_with_operators(path: Path, incident: str, accounts: int) -> dict[str, str]:
    """A roster file of ``accounts`` operators ``op0..`` with random passwords (returned)."""
    import secrets

    from service.protocol.access import Roster, hash_password, save_roster

    roster = Roster(incident=incident)
    passwords = {}
    for i in range(accounts):
        name = f"op{i}"
        passwords[name] = secrets.token_urlsafe(12)
        roster.add(name, "operator").password = hash_password(passwords[name])
    save_roster(path, roster)
    return passwords


def bench_logins(concurrent: int = 20, seconds: float = 5.0, probe_every_s: float = 0.02,
                 timing_trials: int = 15) -> dict:
    import zenoh

    from client.console.server import start_console
    from service.protocol.incident import default_incident
    from service.protocol.session import free_local_port, router_config

    cfg = default_incident()
    with tempfile.TemporaryDirectory() as tmp:
        passwords = roster_with_operators(Path(tmp) / "roster.json", cfg.id, concurrent)
        session = zenoh.open(router_config([f"tcp/127.0.0.1:{free_local_port()}"]))
        console = start_console(session, cfg, port=0, actor="console-1", roster=Path(tmp) / "roster.json")
        try:
            return _measure(console.port, passwords, concurrent, seconds, probe_every_s, timing_trials)
        finally:
            console.close()
            session.close()


def _measure(port, passwords, concurrent, seconds, probe_every_s, timing_trials) -> dict:
    idle = [_get_session(port) for _ in range(50)]
    stop = threading.Event()
    codes: dict[int, int] = {}
    login_s: list[float] = []
    lock = threading.Lock()

    def logger(i: int) -> None:  # one address per login thread; right and wrong passwords in turn
        user = f"op{i}"
        k = 0
        while not stop.is_set():
            pw = passwords[user] if k % 2 == 0 else "wrong"
            status, took = _post_login(port, f"127.0.1.{i + 1}", user, pw)
            with lock:
                codes[status] = codes.get(status, 0) + 1
                login_s.append(took)
            k += 1

    threads = [threading.Thread(target=logger, args=(i,), daemon=True) for i in range(concurrent)]
    for t in threads:
        t.start()
    busy: list[float] = []
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        busy.append(_get_session(port))
        time.sleep(probe_every_s)
    stop.set()
    for t in threads:
        t.join(30)
    known, unknown = [], []
    for k in range(timing_trials):  # fresh addresses and names: no lock in the way
        known.append(_post_login(port, f"127.0.2.{k + 1}", f"op{k % concurrent}", f"nope-{k}")[1])
        unknown.append(_post_login(port, f"127.0.3.{k + 1}", f"ghost{k}", f"nope-{k}")[1])
    ms = 1e3
    k_med, u_med = statistics.median(known), statistics.median(unknown)
    return {
        "concurrent_logins": concurrent, "seconds": seconds, "logins": len(login_s), "login_codes": codes,
        "login_p50_ms": round(_percentile(login_s, 50) * ms, 1), "login_p99_ms": round(_percentile(login_s, 99) * ms, 1),
        "session_idle_p50_ms": round(_percentile(idle, 50) * ms, 2), "session_idle_p99_ms": round(_percentile(idle, 99) * ms, 2),
        "session_probes": len(busy), "session_busy_p50_ms": round(_percentile(busy, 50) * ms, 2),
        "session_busy_p99_ms": round(_percentile(busy, 99) * ms, 2),
        "session_busy_max_ms": round(max(busy) * ms, 2),
        "wrong_password_known_user_median_ms": round(k_med * ms, 1),
        "wrong_password_unknown_user_median_ms": round(u_med * ms, 1),
        "known_over_unknown": round(k_med / u_med, 3),
    }


def bench_logins_command(
    concurrent: int = typer.Option(20, "--concurrent", help="logins at once, each from its own loopback address"),
    seconds: float = typer.Option(5.0, "--seconds", help="how long they go on"),
) -> None:  # pragma: no cover - a CLI wrapper
    """Password logins under load: /api/session latency while N logins run at once, and the
    answer time of known and unknown user names (JSON)."""
    from service.protocol.terminal import print_json

    print_json(bench_logins(concurrent, seconds))

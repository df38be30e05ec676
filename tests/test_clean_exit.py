"""Commands that hold hundreds of wearables end with exit code 0 (issue 29, clean exits).

A process whose zenoh threads are still calling into Python when the interpreter finalises is
aborted by glibc ("FATAL: exception not rethrown", exit code -6): the load generator of
``bench --responders 500`` did so in 2 of 3 runs on a quiet machine. The reproduction here
keeps the wearables' Status subscribers busy to the end (a router puts a Status-sized message
to every walker's status key every 250 ms while ``simulate`` runs and closes: 4,000 callbacks a
second), which is when a callback is most likely in flight. Every 50 ms, the 2 s run of 1,000
walkers took 20 s, 103 s and 187 s in three CI runs (the callbacks starve it), too near the
300 s bound for another machine; at 250 ms it takes 17 s here. Before the fix (main at 220d6c1), the same harness run as
a spawned child with 500 walkers aborted in 1 of 4, 2 of 4 and 1 of 8 runs on this machine.
"""
from __future__ import annotations

import subprocess
import sys
import threading

import pytest

from tests.zenoh_util import router


def _spam_status(session, incident: str, n: int, stop: threading.Event) -> None:
    keys = [f"firetrack/{incident}/sim-{i:03d}/status" for i in range(n)]
    while not stop.is_set():
        for k in keys:
            session.put(k, b"\x80")  # not a Status: each wearable's callback runs and drops it
        stop.wait(0.25)


@pytest.mark.parametrize("walkers", [1000])
def test_simulate_with_many_walkers_exits_zero_while_statuses_arrive(walkers):
    r, ep = router()
    stop = threading.Event()
    spam = threading.Thread(target=_spam_status, args=(r, "exit-test", walkers, stop), daemon=True)
    try:
        spam.start()
        proc = subprocess.run(
            [sys.executable, "-m", "client.entry", "simulate", "-n", str(walkers), "--seconds", "2",
             "--start-spread", "0", "--incident", "exit-test", "--connect", ep],
            capture_output=True, text=True, timeout=300,
        )
    finally:
        stop.set()
        spam.join(5)
        r.close()
    assert "exception not rethrown" not in proc.stderr, proc.stderr[-2000:]
    assert proc.returncode == 0, f"exit code {proc.returncode}: {proc.stderr[-2000:]}"


def test_a_failing_command_still_exits_with_its_code():
    """The exit path that skips finalisation keeps the command's own exit status."""
    proc = subprocess.run([sys.executable, "-m", "client.entry", "eval", "ipin", "/nonexistent/walk.txt"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "file not found" in proc.stderr

"""More than one core: the responders of an incident shared between worker processes.

The per-responder work (numpy and gtsam under Python's GIL) runs on one core per process,
so ``firetrack serve --workers K`` runs K :class:`service.shell.service.IncidentService` workers:
the first in the main process beside the router, the others in their own processes, each
a zenoh client of that router. A worker owns the responders whose id hashes to it
(:func:`service.shell.sharding.in_shard`) and subscribes to their keys only, each when the
responder's presence token appears (:mod:`service.shell.shard_routes`): the others' frames
never reach it (``ServiceSettings.catch_all`` adds the incident's wildcard back, for sources
that announce nothing). Each worker publishes the
poses and status of its own responders and answers ``track`` queries for them; to the
console and the wearables the K workers look like one service.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import sys
import time
from pathlib import Path

CLOSE_TIMEOUT_S = 10.0  # s all workers together get to drain and stop before they are killed


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity), the bound of ``--workers``."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def die_with_parent(parent: int) -> None:
    """Linux: the kernel sends this process SIGKILL when its parent ends, however it ends
    (SIGKILL, a crash, ``os._exit``), so no worker outlives its ``serve``. Elsewhere a no-op."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    PR_SET_PDEATHSIG = 1
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent ended before the request was made
        os._exit(1)


def worker_main(endpoint: str, config: dict, base_dir: str, k: int, n: int, stop, ready, stats_path: str | None,
                log_poses: bool = False, tls_dir: str | None = None,
                roster: str | None = None, settings=None, parent: int | None = None) -> None:  # pragma: no cover - runs in a child process
    from service.protocol.incident import incident_from_dict
    from service.protocol.session import open_client
    from service.shell.service import IncidentService

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops us through ``stop``
    if parent is not None:
        die_with_parent(parent)
    cfg = incident_from_dict(config, base_dir=base_dir)
    tls = access = watcher = None
    if tls_dir is not None:  # the same service identity as worker 0, and the same roster
        from service.protocol.tls import TlsIdentity

        tls = TlsIdentity.load(tls_dir)
    if roster is not None:
        from service.protocol.access import access_message, load_roster

        access = access_message(load_roster(roster), roster)
    session = open_client(endpoint, tls=tls)
    svc = IncidentService(session, cfg, settings, shard=(k, n), access=access, actor=tls.name if tls else "service")
    if roster is not None:
        from service.protocol.access import RosterWatcher

        watcher = RosterWatcher(roster, lambda r: svc.update_access(access_message(r, roster)))
    poses: list = []
    if log_poses:
        svc.pose_hook = lambda rid, msg, oldest: poses.append((rid, oldest, msg.published_at))
    svc.start()
    ready.set()
    stop.wait()
    _drain(svc, quiet_s=0.5, timeout=20.0)
    stats = {"shard": k, "frames_processed": svc.frames_processed, "busy_s": svc.busy_s,
             "tracker_batches": svc.tracker_batches, "frames_not_processed": svc.frame_accounting(),
             "responders": len(svc.responders), "errors": svc.errors, "poses": poses,
             "heard": dict(svc.heard), "routes": len(svc.routes.routes),
             "behind_max_s": svc.behind_max_s}
    if watcher is not None:
        watcher.close()
    svc.close()
    session.close()
    if stats_path:
        Path(stats_path).write_text(json.dumps(stats))
    from service.protocol.terminal import leave_process

    leave_process(0)  # not the interpreter's finalisation under zenoh's threads


def _drain(svc, quiet_s: float, timeout: float) -> None:
    """Until the worker's queue is empty and nothing new has come in for ``quiet_s`` (frames
    still in flight from the router when the stop came are processed, not dropped)."""
    deadline = time.monotonic() + timeout
    last, since = None, time.monotonic()
    while time.monotonic() < deadline:
        svc.wait_idle(max(0.0, deadline - time.monotonic()))
        seen = sum(svc.received.values())
        if seen != last:
            last, since = seen, time.monotonic()
        elif time.monotonic() - since >= quiet_s:
            return
        time.sleep(0.05)


class WorkerPool:
    """Workers 1..K-1 of an incident (worker 0 is the caller's own IncidentService)."""

    def __init__(self, endpoint: str, cfg, n: int, stats_dir: str | None = None, log_poses: bool = False,
                 tls_dir: str | None = None, roster: str | None = None, settings=None, cancel=None):
        """``cancel``: an event (the command's signal stop) that ends the start-up early: no
        more workers are started once it is set."""
        self.cancel = cancel
        self.ctx = mp.get_context("spawn")
        self.stop = self.ctx.Event()
        self.procs = []
        self.stats_paths = []
        config = cfg.model_dump(mode="json")
        base = str(getattr(cfg, "_base_dir", Path.cwd()))
        for k in range(1, n):
            if cancel is not None and cancel.is_set():
                break
            ready = self.ctx.Event()
            path = str(Path(stats_dir) / f"worker{k}.json") if stats_dir else None
            p = self.ctx.Process(target=worker_main,
                                 args=(endpoint, config, base, k, n, self.stop, ready, path, log_poses, tls_dir, roster,
                                       settings,  # the same ServiceSettings as worker 0 (intake, expiry, ...)
                                       os.getpid()),
                                 name=f"firetrack-worker-{k}", daemon=True)
            p.start()
            self.procs.append((p, ready))
            self.stats_paths.append(path)

    def wait_ready(self, timeout: float = 60.0) -> bool:
        """Every worker started within ``timeout`` s (False at once when ``cancel`` is set)."""
        deadline = time.monotonic() + timeout
        for _, ready in self.procs:
            while not ready.wait(0.1):
                if time.monotonic() > deadline or (self.cancel is not None and self.cancel.is_set()):
                    return False
        return True

    def close(self, timeout: float = CLOSE_TIMEOUT_S) -> list[dict]:
        """Stop every worker: ``timeout`` s for all of them together to drain and end, then the
        rest are killed; none is left behind."""
        self.stop.set()
        for p, ready in self.procs:  # still starting: it serves nobody yet, nothing to drain
            if not ready.is_set() and p.is_alive():
                p.kill()
        deadline = time.monotonic() + timeout
        for p, _ in self.procs:
            p.join(max(0.0, deadline - time.monotonic()))
        for p, _ in self.procs:
            if p.is_alive():
                p.kill()
        for p, _ in self.procs:
            p.join(5.0)
        return [json.loads(Path(s).read_text()) for s in self.stats_paths if s and Path(s).exists()]

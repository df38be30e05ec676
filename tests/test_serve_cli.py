"""``firetrack serve`` as a process: starts, serves a wearable, and stops cleanly on SIGINT/SIGTERM."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from client.wearable import Wearable
from service.protocol import wire
from tests.zenoh_util import client, free_port, wait_until


def _serve(port: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "client.entry", "serve", "--no-console", "--listen", f"tcp/127.0.0.1:{port}", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )


def _wait_for_line(proc: subprocess.Popen, text: str, timeout: float = 30.0) -> str:
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line and proc.poll() is not None:
            break
        seen.append(line)
        if text in line:
            return line
    raise AssertionError(f"{text!r} not printed within {timeout} s; got: {''.join(seen)}")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_serve_stops_cleanly_on_a_signal(sig):
    port = free_port()
    proc = _serve(port)
    try:
        _wait_for_line(proc, "serving incident demo")
        cl = client(f"tcp/127.0.0.1:{port}")
        poses = []
        sub = cl.declare_subscriber(wire.key_all("demo", "status"), lambda s: poses.append(s))
        w = Wearable(cl, "demo", "ff1")
        import numpy as np

        t = 100.0 + np.arange(200) / 50.0
        acc = np.tile([0.0, 0.0, 9.81], (200, 1)) + np.c_[np.zeros(200), np.zeros(200), 2.5 * np.sin(2 * np.pi * 1.8 * t)]
        for b in wire.imu_batches_from_arrays("ff1", "d", t, acc, np.zeros((200, 3)), per_batch=5):
            w.send("imu", b)
        assert wait_until(lambda: len(poses) > 0, 10), "no Status from the service"
        w.close()
        sub.undeclare()
        cl.close()
        proc.send_signal(sig)
        rest, _ = proc.communicate(timeout=20)
        assert proc.returncode == 0, rest
        assert "stopped; 1 responder(s)" in rest
    finally:
        if proc.poll() is None:
            proc.kill()


_SIGNAL_TO_A_THREAD = """
import signal, threading, time
from service.protocol.terminal import stop_on_signals
stop = stop_on_signals()
def other_thread():
    time.sleep(0.3)  # the main thread is in stop.wait() by now
    signal.pthread_kill(threading.get_ident(), signal.SIG{name})
threading.Thread(target=other_thread).start()
t0 = time.monotonic()
stop.wait()
print(f"stopped after {{time.monotonic() - t0:.2f}} s")
"""


@pytest.mark.parametrize("name", ["INT", "TERM"])
def test_a_signal_the_kernel_gives_to_another_thread_still_stops_the_command(name):
    """zenoh's runtime threads take a process's signals as often as the main thread does
    (the CI failure of stop 25: ``serve`` ignored SIGINT for 30 s). Here the signal goes to
    another thread on purpose; a plain ``Event.wait()`` would never return."""
    proc = subprocess.run([sys.executable, "-c", _SIGNAL_TO_A_THREAD.format(name=name)], capture_output=True,
                          text=True, timeout=30)
    assert proc.returncode == 0, proc.stderr
    took = float(proc.stdout.split()[2])
    print(f"FIGURE SIG{name} to a non-main thread: the wait ended after {took:.2f} s")
    assert took < 5.0, proc.stdout


def test_serve_refuses_a_bad_config(tmp_path):
    from client.cli import app

    bad = tmp_path / "incident.json"
    bad.write_text(json.dumps({"id": "x", "origin": {"lat": 200, "lon": 0, "alt_m": 0}}))
    r = CliRunner().invoke(app, ["serve", "--config", str(bad), "--seconds", "0", "--no-console"])
    assert r.exit_code == 2
    assert "incident.json" in r.output and "origin" in r.output


def test_schema_command_writes_json_schema(tmp_path):
    from client.cli import app

    out = tmp_path / "schema.json"
    r = CliRunner().invoke(app, ["schema", "--out", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    text = json.dumps(doc)
    for kind in ("ImuBatch", "Fix", "Pose", "Status"):
        assert kind in text


@pytest.mark.parametrize("tls", [False, True])
def test_load_bench_reports_every_figure_and_loses_nothing(tls):
    """``firetrack bench`` end to end at a toy size: a real router, two workers, a publisher process;
    with ``--tls`` every link is mutual TLS and the router enforces the roster's access control,
    and the router runs alone in its process (``--router-process``), worker 0 a client of it."""
    from client.load_bench import bench_service

    r = bench_service(responders=6, seconds=6.0, workers=2, log=lambda m: None, tls=tls, router_process=tls)
    assert r["tls"] is tls and r["router_process"] is tls
    assert (r["router_cpu_s"] > 0) if tls else r["router_cpu_s"] is None  # the router's own process worked
    for key in ("responders", "rate_hz", "samples_per_s", "realtime_factor", "latency_p50_ms", "latency_p99_ms",
                "frames_sent", "frames_processed", "frames_lost", "rss_mb"):
        assert key in r, key
    assert r["frames_sent"] == 6 * 61  # the first frame, then 10 a second
    assert r["frames_lost"] == 0 and r["frames_not_processed"] == {}
    assert r["realtime_factor"] > 1
    assert len(r["behind_max_s_by_worker"]) == 2 and max(r["behind_max_s_by_worker"]) == round(r["behind_max_s"], 2)
    assert 0 < r["latency_p50_ms"] <= r["latency_p99_ms"]


@pytest.mark.parametrize("delay", [0.3, 1.0])
def test_ctrl_c_while_starting_ends_without_a_traceback(delay):
    """A fire officer who presses Ctrl-C while the command is still loading gets a clean exit."""
    proc = subprocess.Popen([sys.executable, "-c", "from client.entry import main; main()", "serve", "--no-console",
                             "--listen", f"tcp/127.0.0.1:{free_port()}"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:  # the Ctrl-C was lost: say so, and leave no service running
        proc.kill()
        out, _ = proc.communicate()
        raise AssertionError(f"Ctrl-C {delay} s into the start did not end it within 30 s:\n{out[-2000:]}") from None
    assert proc.returncode in (0, 130), out
    assert "Traceback" not in out, out


def test_ctrl_c_during_the_warm_up_ends_the_start_at_once(tmp_path):
    """Ctrl-C once the handler is installed (the INSECURE warning is printed just before) lands in
    the warm-up, which takes seconds. It used to go on starting, print "serving" and then stop,
    or hit the stop watchdog 15 s later (exit code 1); now the start ends where it is."""
    proc = subprocess.Popen([sys.executable, "-c", "from client.entry import main; main()", "serve", "--no-console",
                             "--listen", f"tcp/127.0.0.1:{free_port()}"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen = []
    try:
        for line in proc.stdout:  # bounded: the process ends, or is killed below
            seen.append(line)
            if "INSECURE" in line:
                break
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        rest, _ = proc.communicate()
        raise AssertionError("Ctrl-C during the warm-up did not end serve within 30 s:\n" + "".join(seen) + rest) from None
    out = "".join(seen) + rest
    assert proc.returncode in (0, 130), out
    assert "firetrack serving" not in out and "still shutting down" not in out and "Traceback" not in out, out
    assert "stopped while starting" in out or "interrupted" in out, out


def test_a_ctrl_c_before_the_commands_own_handler_says_interrupted(capsys):
    """typer turns a KeyboardInterrupt into a silent exit 130; CI once saw ``serve`` end that way
    with nothing printed, after a Ctrl-C that came before its stop handler. The script says why."""
    import typer

    from client.entry import _run

    app = typer.Typer()

    @app.command()
    def start() -> None:
        raise KeyboardInterrupt  # where the first Ctrl-C lands before stop_on_signals

    before = signal.getsignal(signal.SIGINT)
    try:
        assert _run(lambda: app([], prog_name="firetrack")) == 130
    finally:
        signal.signal(signal.SIGINT, before)  # _run installs the script's own first handler
    assert "interrupted" in capsys.readouterr().err


def test_a_ctrl_c_swallowed_while_importing_still_stops_the_command():
    """A Ctrl-C during the imports that a library swallows (a broad ``except`` around an optional
    import) must still stop the command once its own handler is installed."""
    code = ("import os, signal\n"
            "from service.protocol.early_interrupt import remember_interrupts\n"
            "remember_interrupts()\n"
            "try:\n"
            "    os.kill(os.getpid(), signal.SIGINT)\n"
            "    import time; time.sleep(5)\n"
            "except BaseException:\n"
            "    pass  # what a careless library does\n"
            "from service.protocol.terminal import stop_on_signals\n"
            "print('stop set:', stop_on_signals().is_set())\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert "stop set: True" in r.stdout, r.stdout + r.stderr
    assert "SIGINT: shutting down" in r.stdout + r.stderr


@pytest.mark.parametrize("args, says", [
    (["--roster-only"], "--roster-only needs a roster"),  # the demo incident has none, and no --tls
    (["--expire-after", "0"], "--expire-after must be positive"),
    (["--admit-per-s", "0"], "IntakeSettings.admit_per_s must be positive"),
    (["--max-responders", "0"], "max_responders and bad_after must be at least 1"),
])
def test_serve_refuses_bad_isolation_options_with_the_option_named(tmp_path, args, says):
    from client.cli import app

    r = CliRunner().invoke(app, ["serve", "--seconds", "0", "--no-console", *args])
    assert r.exit_code == 2, r.output
    assert says in " ".join(r.output.split())


def _unit_exec_start(unit_text: str) -> list[str]:
    """The ``ExecStart=`` command line of a systemd unit (continuation lines joined)."""
    import shlex

    text = unit_text.replace("\\\n", " ")
    line = next(x for x in text.splitlines() if x.startswith("ExecStart="))
    return shlex.split(line.split("=", 1)[1])


def test_the_systemd_unit_restarts_serve_after_sigkill_on_its_fixed_recording_path(tmp_path):
    """What systemd does with ``deploy/firetrack.service``: the unit's own command (paths and
    endpoints mapped to this machine), SIGKILL once snapshots exist, the same command again after
    ``RestartSec`` (it resumes, never refuses), then ``KillSignal`` and a clean exit within
    ``TimeoutStopSec``."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    unit = (root / "deploy" / "firetrack.service").read_text()
    settings = dict(x.split("=", 1) for x in unit.replace("\\\n", " ").splitlines() if "=" in x and not x.startswith("#"))
    assert settings["Restart"] in ("on-failure", "always", "on-abnormal")  # SIGKILL is a failure for all three
    assert settings["KillSignal"] == "SIGTERM"
    argv = _unit_exec_start(unit)
    assert argv[0].endswith("/firetrack") and argv[1] == "serve"
    port, web = free_port(), free_port()
    mapped = {"--tls": [],  # plain TCP on loopback here: no certificates (tests/test_security*.py cover TLS)
              "--connect": ["--listen", f"tcp/127.0.0.1:{port}"],  # no separate router here
              "--config": ["--config", str(root / "deploy" / "incidents" / "ipin-museum.json")],
              "--record": ["--record", str(tmp_path / Path(argv[argv.index("--record") + 1]).name.replace("%N", "firetrack"))],
              "--port": ["--port", str(web)]}
    cmd = [sys.executable, "-m", "client.entry", "serve"]
    rest = iter(argv[2:])
    for a in rest:
        assert a in mapped, f"an option of the unit this test does not know: {a}"
        cmd += mapped[a]
        next(rest)
    record = Path(mapped["--record"][1])
    state = record.with_name(record.name + ".state")
    cfg_id = json.loads((root / "deploy" / "incidents" / "ipin-museum.json").read_text())["id"]

    def start():
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        seen = []
        while not seen or "serving incident" not in seen[-1]:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, "".join(seen)
            seen.append(line)
        return proc, "".join(seen)

    proc, _ = start()
    session = None
    try:
        session = client(f"tcp/127.0.0.1:{port}")
        w = Wearable(session, cfg_id, "alpha")
        z = np.zeros((10, 3))
        z[:, 2] = 9.81
        seq = 0

        def send(n):
            nonlocal seq
            for _ in range(n):
                w.send("imu", wire.ImuBatch(responder="alpha", device="d", seq=seq, t=10.0 + seq * 0.1 + np.arange(10) * 0.01,
                                            acc=z, gyr=np.zeros((10, 3))))
                seq += 1
                time.sleep(0.02)

        send(50)
        from service.review.resume import StateFile

        def snapshot_holds_the_frames():  # a snapshot beside the recording, taken after the 50 frames
            try:
                return StateFile.read(state)["position"] >= 50
            except (OSError, ValueError):
                return False
        assert wait_until(snapshot_holds_the_frames, 30, 0.2)
        proc.kill()  # SIGKILL
        assert proc.wait(10) == -signal.SIGKILL
        time.sleep(float(settings["RestartSec"]))
        proc, started = start()  # systemd: the same command line
        assert "resumed incident" in started and "1 responder(s)" in started, started
        send(20)
        proc.send_signal(signal.SIGTERM)
        rest_out, _ = proc.communicate(timeout=float(settings["TimeoutStopSec"]))
        assert proc.returncode == 0, rest_out
        assert record.with_name(record.stem + ".1.mcap").exists()
        w.close(0.0)
    finally:
        if session is not None:
            session.close()
        if proc.poll() is None:
            proc.kill()


def test_without_a_config_an_install_without_the_demo_config_says_what_to_give(monkeypatch, tmp_path, capsys):
    """A wearable-only install (no deploy/ folder) asked for the default incident: a clear error, not a missing path."""
    import typer

    from service.protocol import incident as incidents
    from service.protocol.terminal import incident_or_exit

    monkeypatch.setattr(incidents, "DEFAULT_INCIDENT_PATH", tmp_path / "nowhere" / "ipin-museum.json")
    with pytest.raises(typer.Exit) as e:
        incident_or_exit(None)
    assert e.value.exit_code == 2
    out = capsys.readouterr()
    assert "--config FILE" in out.out + out.err


def _children(pid: int) -> list[int]:
    """The live processes whose parent is ``pid`` (from /proc)."""
    import os

    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) ": state, ppid, ...
        if int(fields[1]) == pid and fields[0] != "Z":
            out.append(int(entry))
    return out


def _alive(pids: list[int]) -> list[int]:
    import os

    alive = []
    for p in pids:
        try:
            with open(f"/proc/{p}/stat") as f:
                if f.read().split(") ", 1)[1][0] != "Z":
                    alive.append(p)
        except OSError:
            pass
    return alive


def test_serve_refuses_more_workers_than_cores_with_one_line_and_starts_nothing():
    """Issue 32, part 6: ``serve --workers 100000`` was a process storm (load 394, the OOM killer)."""
    import multiprocessing

    from client.cli import app
    from service.shell.workers import usable_cores

    for n in (100_000, 0, -3, usable_cores() + 1):
        r = CliRunner().invoke(app, ["serve", "--workers", str(n), "--seconds", "0", "--no-console"])
        assert r.exit_code == 2, r.output
        assert r.output.count("\n") == 1 and f"--workers must be between 1 and {usable_cores()}" in r.output
        assert f"got {n}" in r.output
    assert multiprocessing.active_children() == []


@pytest.mark.parametrize("how", ["SIGTERM", "SIGKILL"])
def test_serve_with_two_workers_leaves_no_process_behind(how):
    """SIGTERM: serve ends within seconds, its worker process with it; SIGKILL (no goodbye):
    the worker dies with its parent (PR_SET_PDEATHSIG)."""
    from service.shell.workers import usable_cores

    if usable_cores() < 2:
        pytest.skip("--workers 2 needs 2 cores")
    port = free_port()
    proc = _serve(port, "--workers", "2")
    try:
        _wait_for_line(proc, "serving incident demo", timeout=120)
        assert wait_until(lambda: len(_children(proc.pid)) >= 1, 30)
        workers = _children(proc.pid)
        t0 = time.monotonic()
        proc.send_signal(getattr(signal, how))
        rest, _ = proc.communicate(timeout=30)
        took = time.monotonic() - t0
        assert wait_until(lambda: not _alive(workers), 10), f"left behind: {_alive(workers)}"
        print(f"FIGURE serve --workers 2, {how}: ended in {took:.2f} s, {len(workers)} child process(es), none left")
        if how == "SIGTERM":
            assert proc.returncode == 0 and took < 15.0, rest
            assert "stopped;" in rest and "Traceback" not in rest
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.parametrize("name, text", [
    ("deep.json", "[" * 100_000 + "]" * 100_000),
    ("huge.toml", "floor_height_m = 1e308\n[origin]\nlat = 49.46\nlon = 11.11\n"),
    ("floors.json", json.dumps({"origin": {"lat": 49.46, "lon": 11.11}, "floors": [{"number": i} for i in range(200_000)]})),
])
def test_serve_refuses_a_hostile_config_with_one_short_line(tmp_path, name, text):
    """Issue 32, part 6: a 100,000-deep config gave a RecursionError traceback, 1e308 was taken,
    200,000 floors gave a 4.4 MB error line."""
    import multiprocessing

    from client.cli import app

    f = tmp_path / name
    f.write_text(text)
    r = CliRunner().invoke(app, ["serve", "--config", str(f), "--seconds", "0", "--no-console"])
    assert r.exit_code == 2 and isinstance(r.exception, SystemExit), r.output[:500]
    assert r.output.count("\n") == 1 and len(r.output) < 1200 and name in r.output, r.output[:500]
    assert "Traceback" not in r.output and multiprocessing.active_children() == []

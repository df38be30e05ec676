"""The load bench's per-stage table from a profile: sums, units and the worker's idle wait."""
from types import SimpleNamespace

from client.load_bench import STAGES, stage_table


def _entry(cum: float, callers: dict | None = None):
    return (1, 1, 0.0, cum, callers or {})  # cProfile's (cc, nc, tottime, cumtime, callers)


def test_stage_table_sums_stages_per_frame_and_step_and_takes_the_idle_wait_out():
    take_queued = ("/x/service/shell/round_intake.py", 240, "take_queued")
    stats = SimpleNamespace(stats={
        ("/x/service/shell/service.py", 260, "_run_round"): _entry(2.0),
        take_queued: _entry(0.7),
        ("/x/service/shell/round_intake.py", 217, "take_frames"): _entry(0.1),
        # blocked in queue.get for 0.5 s when called from take_queued; 0.25 s from elsewhere is not the worker's wait
        ("/usr/lib/python3.11/queue.py", 154, "get"): _entry(0.75, {take_queued: (1, 1, 0.0, 0.5),
                                                                    ("/x/other.py", 1, "f"): (1, 1, 0.0, 0.25)}),
        ("/x/service/protocol/codec.py", 68, "decode"): _entry(0.3),
        ("/x/pdr/fleet_kernels.py", 166, "heading_stage"): _entry(0.4),
        ("/x/pdr/heading.py", 300, "answer_steps"): _entry(0.1),  # the per-step part counts in the same row
        ("/x/pdr/other.py", 1, "update"): _entry(9.0),  # same function name, another file: not a stage
    })
    table = stage_table(stats, frames=1000, steps=100)
    assert set(STAGES) <= set(table)
    assert table["decode"] == {"us_per_frame": 300.0, "us_per_step": 3000.0}
    assert table["heading (AHRS, bias, compass, per step)"]["us_per_frame"] == 500.0
    assert table["idle (waiting for input)"]["us_per_frame"] == 500.0
    assert table["zenoh take"]["us_per_frame"] == 300.0  # 0.7 + 0.1 - 0.5 s
    assert table["worker total"]["us_per_frame"] == 2300.0  # 2.0 + 0.7 + 0.1 - 0.5 s
    assert table["status"]["us_per_frame"] == 0.0


def test_boot_streams_give_a_share_of_wearers_boot_signals_without_magnetometer_and_continue_across_frames():
    import numpy as np
    import pytest

    from client.simulate import BootStreams

    n, rate = 6, 100.0
    boots = BootStreams(n, 0.5, rate, 1000.0, seed=2)
    assert boots.count == 3
    b = SimpleNamespace(t=1000.0 + np.arange(10) / rate, acc=np.zeros((10, 3)), gyr=np.zeros((10, 3)),
                        mag=np.ones((10, 3)), pressure_t=np.array([1000.0]), pressure=np.array([1013.0]))
    first = boots.signals(0, b)
    second = boots.signals(0, b)
    assert first["carry"] == "foot" and "mag" not in first and "pressure" not in first
    acc, _ = boots._walks[0]
    assert np.array_equal(np.vstack((first["acc"], second["acc"])), acc[:20])  # the walk goes on, frame by frame
    assert abs(np.linalg.norm(first["acc"][0]) - 9.81) < 0.5  # a boot at rest first: gravity only
    hand = boots.signals(5, b)
    assert hand["carry"] == "handheld" and hand["mag"] is b.mag and hand["pressure"] is b.pressure
    assert BootStreams(n, 0.0, rate, 1000.0, seed=2).count == 0
    with pytest.raises(ValueError, match="share of boot-mounted"):
        BootStreams(n, 1.5, rate, 1000.0, seed=2)


def test_bench_decode_reports_both_paths_for_every_run():
    import json

    from typer.testing import CliRunner

    from client.cli import app

    r = CliRunner().invoke(app, ["bench", "decode", "--frames", "20", "--runs", "2"])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert len(d["fast_path_us_per_frame"]) == 2 and len(d["schema_path_us_per_frame"]) == 2
    assert all(x > 0 for x in d["fast_path_us_per_frame"] + d["schema_path_us_per_frame"])


def test_a_drill_crew_steps_alike_where_a_mixed_crew_does_not():
    """The bench's --drill crew (client.simulate.DRILL_CREW): every wearer takes the same steps
    per second once walking, so tracked_evenly's pose rates measure the service; the default
    crew's pauses and cadences spread them by more than 20 % over the same window."""
    import numpy as np

    from client.load_bench import _even_from
    from client.simulate import DRILL_CREW
    from pdr.simulation import WalkerFleet, WalkerSettings

    n, spread, seconds = 24, 5.0, 24.0
    lo = _even_from(True, spread)  # s after the start: every wearer walks from here on
    assert lo == spread + WalkerSettings().initial_still_s + 3.0 and _even_from(False, spread) == 3.0
    spreads = {}
    for name, kw in (("drill", DRILL_CREW), ("mixed", {})):
        fleet = WalkerFleet(n, WalkerSettings(rate_hz=100.0, **kw), 0, floors=(0, 0), start_t=1000.0, attitude=False)
        for i, w in enumerate(np.random.default_rng([0, 0x5747]).uniform(0.0, spread, n)):
            fleet.stand_still(i, float(w), at=1000.0)  # as the bench's publisher starts its crew
        at_lo, at_end = np.zeros(n), np.zeros(n)
        for _ in range(int(seconds * 10)):
            for i, b in enumerate(fleet.next_batches(10)):
                if b.t[-1] - 1000.0 <= lo:
                    at_lo[i] = b.step_count[-1]
                at_end[i] = b.step_count[-1]
        rate = (at_end - at_lo) / (seconds - lo)
        spreads[name] = float(np.abs(rate - np.median(rate)).max() / np.median(rate))
    assert spreads["drill"] <= 0.1, spreads  # whole steps in a 14 s window: one step is 4 %
    assert spreads["mixed"] > 0.2, spreads


def test_tracked_evenly_counts_the_frames_in_which_everyone_walks_and_still_sees_a_slow_responder():
    """A service behind publishes, inside the bench's wall-time window, the poses of frames from
    before a late starter walked; its walk's first steps come out four at once when it is
    confirmed. Counted from the frames in which everyone walks (``seq_from``), a late starter
    tracked at the service's pace has the same rates as an early one, and a responder that the
    service advances half as fast is still measured at half."""
    from client.load_bench import _even

    poses = []
    for k in range(30):  # a round a second, each runs 5 frames of every responder; a step (a pose) every 5 frames
        poses.append(("early", 5 * k, float(k)))
        if k == 12:  # walking from frame 40, confirmed at frame 60: its steps so far come out together
            poses += [("late", 60, 12.0)] * 5
        elif k > 12:
            poses.append(("late", 5 * k, float(k)))
        if k % 2 == 0:  # advanced half as fast: 5 frames (a step) every other round
            poses.append(("slow", 5 * (k // 2), float(k)))
    d = _even(poses, ["early", "late"], 5.0, 29.0, 1)
    assert d["poses_per_s"]["max"] > 1.2 * d["poses_per_s"]["min"], d  # the confirmed steps counted as if paced
    d = _even(poses, ["early", "late"], 5.0, 29.0, 1, seq_from=65)
    assert d["poses_per_s"]["min"] == d["poses_per_s"]["max"] == 1.0, d
    assert d["frames_per_s"]["min"] == d["frames_per_s"]["max"] == 5.0, d
    d = _even(poses, ["early", "late", "slow"], 5.0, 29.0, 1, seq_from=30)
    assert d["frames_per_s"]["min"] == 2.5 and d["poses_per_s"]["min"] == 0.5 and d["poses_per_s"]["spread"] == 0.5, d

"""Shared pytest fixtures.

Real recordings live outside the repository, in ``../shared/data`` next to the project root
(see that folder's README; ``FIRETRACK_SHARED_DATA`` names another folder, e.g. from a git
worktree); tests that need one ask the ``shared_data`` fixture, which skips
the test with the missing path when the recording is absent.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from hypothesis import settings

# No per-example deadline: speed is measured by the benchmarks, not by tests, and CI machines
# (and a busy laptop) are slower than the one a deadline would be tuned on.
settings.register_profile("firetrack", deadline=None)
settings.load_profile("firetrack")

SHARED_DATA = Path(os.environ.get("FIRETRACK_SHARED_DATA") or Path(__file__).resolve().parents[1].parent / "shared" / "data")


def shared_data_path(relpath: str | Path) -> Path:
    """Path of a recording under ../shared/data, or skip the calling test when it is absent."""
    path = SHARED_DATA / relpath
    if not path.exists():
        pytest.skip(f"recording {path} not present")
    return path


@pytest.fixture
def shared_data():
    """``shared_data("ipin2023/...")`` -> Path, skipping the test when the recording is absent."""
    return shared_data_path


# ---------------------------------------------------------------------------------------------
# Tiers. Every test gets exactly one of ``unit``, ``slow``, ``integration`` and ``browser``
# (pyproject.toml registers them), decided here from what the test reaches rather than written
# on each test:
#   browser      it asks for the ``browser`` fixture (Chromium through Playwright);
#   integration  its code, the fixtures it asks for, or the helpers of tests/ they call, name a
#                live part: a zenoh session or router, a subprocess, the service's zenoh shell
#                (service.shell), the console's HTTP server, a network client; or it is listed in
#                INTEGRATION below (what that look cannot see, with the reason);
#   slow         a unit test listed in SLOW below, with the CPU time it was measured to take;
#   unit         everything else: in process, no network, no child process.
# ``recording`` is added to every test that reads ../shared/data (the ``shared_data`` fixture,
# ``shared_data_path`` or ``SHARED_DATA``). A unit test that opens a zenoh session or starts one
# of the project's processes anyway fails saying so (``_unit_stays_in_process``), so a tier
# cannot silently be wrong.
# ---------------------------------------------------------------------------------------------
import inspect  # noqa: E402
import types  # noqa: E402

# Names whose mere use means a live part (imported at the top or inside the test): modules, and
# the benches that start a router, a service and wearable processes.
_LIVE_NAMES = {"zenoh", "subprocess", "Popen", "playwright", "sync_playwright", "aiohttp", "urllib", "socket",
               "multiprocessing", "bench_faults", "bench_service"}
# Modules whose objects are live parts: zenoh, the service's zenoh shell, the console's server.
_LIVE_MODULES = ("zenoh", "playwright", "subprocess", "service.shell", "client.console.server")
_RECORDING_NAMES = {"shared_data", "shared_data_path", "SHARED_DATA"}

# Tests the look at the code cannot classify, nodeid -> why (e.g. a command run in process that
# starts a router): none at the time of writing; the guard below names any that appears.
INTEGRATION: dict[str, str] = {
    "tests/test_foxglove.py::test_serve_foxglove_prints_where_to_connect":
        "runs serve in process (CliRunner): its router and the Foxglove server",
    "tests/test_foxglove.py::test_serve_foxglove_without_the_package_names_the_extra":
        "runs serve in process (CliRunner) up to its router",
}

# Unit-candidate tests moved to ``slow``: nodeid (without parameters) -> CPU seconds measured
# (all cases together) and why. Measured with a per-test ``time.process_time`` over
# ``pytest -m unit`` on the 2-core machine shared with other jobs (load 20-70); every unit test
# of 0.5 s or more is here. Together they took 93 of the 120 CPU seconds of the unit tests;
# without them ``pytest -m unit`` ran 670 tests in 37 s of CPU (user + sys, collection included).
# The entries from the regression guard on (issue 30) were measured with ``FIRETRACK_TEST_CPU=file``,
# which writes each test's own CPU seconds (``time.process_time`` over setup, call and teardown)
# to ``file``: the 16 of them run together (their numba compilations paid by the first); without
# them ``pytest -m unit`` ran 738 tests in 45.5 s user + 2.2 s sys (``/usr/bin/time -v``, load 6-8).
SLOW: dict[str, str] = {
    "tests/test_ipin_eval.py::test_eval_ipin_cv_on_real_walks_with_a_folder_glob":
        "15.8 s: eval ipin --cv over a folder of real walks",
    "tests/test_fleet.py::test_simulated_walkers_alone_and_in_a_fleet_give_the_same_events":
        "8.4 s: a simulated crowd, each walker alone and in the fleet",
    "tests/test_intake.py::test_memory_is_bounded_under_a_stream_of_hostile_input":
        "5.3 s: a long stream of hostile input",
    "tests/test_ahrs_invariance.py::test_the_same_orientation_at_every_sample_rate":
        "4.8 s: every filter at every sample rate (5 cases)",
    "tests/test_floors_buildings.py::test_simulated_buildings_floor_right_at_every_dwell":
        "4.5 s: simulated buildings and walks (6 cases)",
    "tests/test_fleet.py::test_real_walks_alone_and_in_a_fleet_give_the_same_events":
        "4.3 s: real walks, alone and in the fleet",
    "tests/test_fusion.py::test_marginalisation_keeps_the_state_bounded":
        "3.3 s: a long synthetic walk through the smoother",
    "tests/test_wire.py::test_fast_path_answers_spoiled_fields_as_the_schema":
        "2.7 s: hypothesis, both decoders per example",
    "tests/test_io.py::test_real_ipin_all_files_load":
        "2.4 s: every real IPIN file",
    "tests/test_wire.py::test_fuzz_field_values":
        "2.1 s: hypothesis fuzz",
    "tests/test_fleet.py::test_the_service_gives_a_responder_the_same_poses_alone_or_beside_others":
        "the core four times over walks",
    "tests/test_fusion.py::test_pdr_heading_slows_gyro_drift_and_its_offset_state_is_the_price":
        "2.0 s: long synthetic walks, with and without",
    "tests/test_resume.py::test_a_crashed_service_resumes_and_reprocess_equals_the_live_poses":
        "1.9 s: an 80 s walk recorded, crashed, resumed (3 cases)",
    "tests/test_service.py::test_rounds_of_any_size_give_the_same_poses_bit_for_bit":
        "1.7 s: the core over walks in several round sizes",
    "tests/test_extension_points.py::test_a_motion_model_registered_from_a_test_tracks_its_carry_position":
        "1.7 s: the core with both engines",
    "tests/test_fleet.py::test_a_crowd_that_leaves_gives_its_rows_back_and_the_fleet_goes_on":
        "1.7 s: a crowd through the fleet",
    "tests/test_ipin_eval.py::test_each_route_is_scored_with_the_setting_chosen_on_the_others":
        "1.6 s: cross-validation over walks",
    "tests/test_floors_buildings.py::test_with_fixed_configured_levels_the_same_walks_go_wrong":
        "1.4 s: simulated buildings and walks",
    "tests/test_streams.py::test_stillness_across_an_outage_is_no_man_down_until_seen_for_the_no_motion_time":
        "1.4 s: minutes of frames through the core",
    "tests/test_wire.py::test_fast_path_decodes_every_valid_frame":
        "1.3 s: hypothesis",
    "tests/test_fusion.py::test_pdr_heading_offset_absorbs_a_heading_that_is_off_for_a_whole_corridor":
        "1.2 s: long synthetic walks",
    "tests/test_fleet.py::test_a_floor_anchored_mid_walk_is_anchored_the_same_in_the_fleet":
        "1.1 s: walks alone and in the fleet",
    "tests/test_fleet.py::test_a_pickled_fleet_goes_on_like_the_original":
        "1.1 s: walks alone and in the fleet",
    "tests/test_examples.py::test_track_a_walk_plots_a_position_for_every_step_of_the_pipeline":
        "1.1 s: a real walk, twice, and a plot",
    "tests/test_broad.py::test_eval_ahrs_with_the_vqf_baseline_side_by_side":
        "1.1 s: two filters over a file, matplotlib",
    "tests/test_incident.py::test_a_real_landmark_lands_on_its_marker_in_the_image":
        "1.0 s: a real recording and the plan image",
    "tests/test_resume.py::test_a_responders_kept_pickle_is_its_pickle_now_whenever_a_snapshot_reuses_it":
        "1.0 s: many snapshots of a walking core",
    "tests/test_ahrs_invariance.py::test_the_rate_test_catches_gains_per_sample":
        "0.9 s: filters at several rates",
    "tests/test_review.py::test_exercise_and_reprocess_commands":
        "0.9 s: exercise and reprocess on real walks",
    "tests/test_ingest.py::test_any_permutation_within_the_window_is_released_in_order_exactly_once":
        "0.9 s: hypothesis",
    "tests/test_ahrs_recordings_defaults.py::test_default_filter_beats_vqf_on_broad":
        "0.9 s: every BROAD trial, two filters",
    "tests/test_wire.py::test_fast_path_answers_mutated_frames_as_the_schema":
        "0.9 s: hypothesis",
    "tests/test_pipeline.py::test_live_frames_give_the_same_events_as_one_batch":
        "0.9 s: a real walk in four frame sizes",
    "tests/test_pipeline.py::test_eval_ipin_command_scores_landmarks":
        "0.8 s: eval ipin on a real walk",
    "tests/test_eval_zupt.py::test_eval_zupt_table_plots_and_options":
        "0.8 s: eval zupt with plots",
    "tests/test_examples.py::test_fuse_a_walk_solves_one_pose_a_step_and_holds_the_checkpoints":
        "0.8 s: a real walk and its factor graph",
    "tests/test_fusion.py::test_bench_fusion_runs_and_converges":
        "0.8 s: bench fusion",
    "tests/test_streams.py::test_the_core_asks_for_a_gap_at_once_and_the_resent_frames_give_the_uninterrupted_track":
        "0.7 s: the core twice over a walk",
    "tests/test_resume.py::test_bench_resume_resumes_from_the_snapshot_to_the_same_core_as_a_whole_replay":
        "0.6 s: bench resume",
    "tests/test_resume.py::test_a_crowd_of_new_responders_is_pickled_a_batch_per_round_before_the_snapshot":
        "0.6 s: a crowd through snapshots",
    "tests/test_ingest.py::test_duplicates_are_never_released_twice":
        "0.6 s: hypothesis",
    "tests/test_streams.py::test_a_restarted_wearable_continues_the_track_on_its_new_clock":
        "0.6 s: the core over two streams",
    "tests/test_ingest.py::test_arbitrary_arrivals_release_in_order_once_and_counts_add_up":
        "0.6 s: hypothesis",
    "tests/test_wire.py::test_fuzz_mutated_valid_payloads":
        "0.6 s: hypothesis fuzz",
    "tests/test_resume.py::test_a_restored_core_goes_on_like_the_uninterrupted_one":
        "0.5 s: the core twice over a walk",
    "tests/test_fleet.py::test_a_released_slot_serves_a_new_member_as_a_fresh_pipeline":
        "0.5 s: walks through the fleet",
    "tests/test_streams.py::test_an_outage_is_counted_in_frames_and_seconds_and_raises_no_man_down":
        "0.5 s: minutes of frames through the core",
    "tests/test_wire.py::test_every_message_round_trips":
        "0.5 s: hypothesis",
    "tests/test_quaternion.py::test_matrix_round_trip_and_angle":
        "0.5 s: hypothesis",
    "tests/test_ipin_regression_guard.py::test_no_development_walk_got_worse_than_its_baseline":
        "72.6 s (first of its run: with the numba compilations): eval ipin --check-baseline over the development walks",
    "tests/test_breadcrumbs.py::test_a_dropped_beacon_takes_the_responders_estimate_and_its_scans_become_fixes":
        "2.2 s: a walk with BLE scans through the core, every scan a fix",
    "tests/test_ipin_submission.py::test_the_submission_files_reproduce_eval_ipins_p75_to_a_centimetre":
        "2.5 s: eval ipin and the submission files",
    "tests/test_ipin_eval.py::test_replayed_dead_reckoning_gives_the_same_tracks_bit_for_bit":
        "1.4 s (all cases): real walks replayed through the core",
    "tests/test_ahrs.py::test_streaming_in_batches_equals_one_batch":
        "0.5 s (10 cases): a recording in several batchings",
    "tests/test_streams.py::test_a_fix_after_a_gap_re_anchors_the_track":
        "1.2 s (2 cases): minutes of frames through the core",
    "tests/test_ipin_robustness.py::test_eval_ipin_perturb_and_baseline_on_a_real_walk":
        "6.5 s: the perturbation suite on a real walk",
    "tests/test_ipin_robustness.py::test_the_suite_scores_each_perturbation_as_eval_ipin_would":
        "1.1 s: every perturbation scored twice",
    "tests/test_incident.py::test_sizes_and_values_are_bounded_and_errors_are_one_short_line":
        "1.1 s (all cases): configs of 200,000 entries",
    "tests/test_fix_attacks.py::test_a_forged_or_absurd_fix_moves_no_track_far_and_stops_none":
        "4.7 s (all cases): a walk per forged fix",
    "tests/test_fix_attacks.py::test_a_drag_of_consistent_checkpoints_is_bounded_and_counted":
        "1.2 s: a walk dragged by checkpoints",
    "tests/test_fix_attacks.py::test_a_fix_the_graph_cannot_take_restarts_the_track_with_an_alarm_within_2_s":
        "1.1 s: a walk and a graph restart",
    "tests/test_grip.py::test_batching_does_not_change_the_headings":
        "1.0 s: a walk in several batchings",
    "tests/test_grip.py::test_a_walk_without_a_change_keeps_the_texting_grip":
        "0.5 s: a simulated walk",
    "tests/test_grip.py::test_without_detection_the_walk_goes_sideways":
        "0.6 s: a simulated walk, twice",
    "tests/test_grip.py::test_a_turn_of_the_phone_in_the_hand_is_not_a_turn_of_the_walker":
        "0.6 s: a simulated walk",
    "tests/test_phone_walk_choice.py::test_the_browser_tests_stretch_is_tracked_alike_at_a_browsers_sampling":
        "2.9 s: a real walk tracked nine times",
    "tests/test_man_down_prompt.py::test_a_still_responder_is_asked_before_man_down_is_raised_at_the_time_it_said":
        "4.0 s: 90 s of frames through the core",
    "tests/test_man_down_prompt.py::test_an_answer_starts_the_no_motion_clock_again_and_no_answer_then_raises_man_down":
        "1.1 s: 90 s of frames through the core",
    "tests/test_man_down_prompt.py::test_an_answer_from_before_the_stillness_changes_nothing":
        "1.2 s: 90 s of frames through the core",
}


# Tests that must have the machine to themselves: their assertions measure rates, latencies or
# a browser's sampling pace, which a busy neighbour bends. The README's test command runs the
# rest on parallel workers (pytest-xdist) and these afterwards, one at a time (``-m serial``).
# Key: a file (every test in it) or a nodeid without parameters -> why.
SERIAL: dict[str, str] = {
    "tests/test_overload.py::test_an_overloaded_worker_tracks_everyone_alike_loses_nothing_and_says_it_is_behind":
        "a worker slowed to 50 frames/s must spread them alike over 8 walkers in real time",
    "tests/test_clean_exit.py::test_simulate_with_many_walkers_exits_zero_while_statuses_arrive":
        "1000 simulated walkers at 100 Hz against a live service: every core it can get",
    # (the whole file before issue 30's suite time; its other tests count frames, acknowledgements
    # and units, and share the file's module fixtures in the parallel phase: SHARED_SETUP)
    "tests/test_phone_browser.py::test_a_real_ipin_walk_played_into_the_phones_sensors_tracks_like_the_recording":
        "Chromium's motion events at a browser's sampling pace, a real walk scored in metres",
    "tests/test_standby.py": "a takeover within 10 s of a killed primary",
    "tests/test_console_browser.py::test_the_page_keeps_up_with_200_responders":
        "the page's draw and frame-interval p95 (a phase-1 run on three workers at load 15: frame p95 250 ms > 200)",
    "tests/test_console_logins.py::test_known_and_unknown_names_take_the_same_time_to_refuse":
        "the ratio of two medians of 9 password checks of ~40 ms (CI at b0f3288, beside the other worker: 1.70 > 1.25)",
}

# Tests on real-time schedules (outages of 10 s and 40 s, a router restart, a flood, forged
# streams against the 6 s takeover rule, shard processes on a mesh): most of their time is
# waiting, so they run in the parallel phase, one after another within a lane (an xdist group,
# ``--dist loadgroup``: one worker each). Two lanes run side by side: each test starts its own
# router, service and wearables on free loopback ports, so two schedules share nothing but the
# CPU, and their assertions are counts and tracks, not rates. Key: a file -> (lane, why).
REALTIME: dict[str, tuple[str, str]] = {
    "tests/test_faults.py": ("realtime_a", "outages, a router restart, a killed service and a flood on real-time schedules"),
    "tests/test_shards.py": ("realtime_a", "worker processes and a mesh of routers tracking walkers in real time"),
    "tests/test_faults_tls.py": ("realtime_b", "outages and a killed service on real-time schedules, with TLS"),
    "tests/test_attacks_tls.py": ("realtime_b", "an honest wearable's frames against forged streams within the takeover time"),
    # (serial before issue 30's suite time: its assertions are that every part of the bench runs and
    # reports consistent figures, none a rate or a latency; 52.6 and 60.1 s under load 2-3)
    "tests/test_fault_bench.py": ("realtime_b", "the fault bench: a service, walkers and an attacker on a real-time schedule"),
}

# Test files whose module-scoped fixture costs seconds: every test of the file on one worker
# (an xdist group of its own), so the fixture is built once and not once per worker (CI's run
# at 7fd9de3 built test_foxglove's on both: 19.6 s and 18.2 s). Key: a file -> the fixture's
# setup, measured with ``pytest --setup-only --durations`` (load 3).
SHARED_SETUP: dict[str, str] = {
    "tests/test_foxglove.py": "22 s: a recorded live incident with the Foxglove server, and its export",
    "tests/test_ahrs_recordings_defaults.py": "9 s: every BROAD trial through two filters",
    "tests/test_phone_browser.py": "1.6-2.6 s (phase-1 runs, load 8-15): Chromium with the sensor flags, a router, service and console",
}


def _listed(item, table: dict):
    """The entry of ``table`` for the item: by its nodeid (without parameters), else its file; or None."""
    base = item.nodeid.split("[", 1)[0]
    return table.get(base, table.get(base.split("::", 1)[0]))


def _code_names(code: types.CodeType) -> set[str]:
    names = set(code.co_names) | set(code.co_varnames) & _LIVE_NAMES
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names |= _code_names(const)
    return names


def _reaches(obj, seen: set[int]) -> set[str]:
    """What the code of ``obj`` (a test, a fixture, a helper of tests/) reaches: ``live``,
    ``recording``; helpers and classes defined under tests/ are followed, the project's own code
    is judged by the module it comes from."""
    if id(obj) in seen:
        return set()
    seen.add(id(obj))
    found: set[str] = set()
    module = getattr(obj, "__module__", None) or ""
    if module.startswith(_LIVE_MODULES):
        return {"live"}
    if isinstance(obj, types.ModuleType):
        return {"live"} if obj.__name__.startswith(_LIVE_MODULES) else set()
    if isinstance(obj, type):
        if not module.startswith("tests"):
            return set()
        for member in vars(obj).values():
            found |= _reaches(getattr(member, "__func__", member), seen)
        return found
    func = inspect.unwrap(obj) if callable(obj) else None
    code = getattr(func, "__code__", None)
    if code is None or not (module.startswith("tests") or module == "conftest"):
        return set()
    names = _code_names(code)
    if names & _LIVE_NAMES:
        found.add("live")
    if names & _RECORDING_NAMES:
        found.add("recording")
    scope = func.__globals__
    for name in names:
        target = scope.get(name)
        if isinstance(target, types.ModuleType) and target.__name__.startswith("tests"):
            for attr in names:  # tests.zenoh_util.router(...): follow the attributes named
                if hasattr(target, attr):
                    found |= _reaches(getattr(target, attr), seen)
        elif target is not None and not isinstance(target, (int, float, str, bytes, tuple, dict, list)):
            found |= _reaches(target, seen)
    return found


def _tier_of(item) -> tuple[str, set[str]]:
    fixtures = set(getattr(item, "fixturenames", ()))
    reached: set[str] = set()
    seen: set[int] = set()
    if "shared_data" in fixtures:
        reached.add("recording")
    reached |= _reaches(getattr(item, "function", None), seen)
    for name, defs in getattr(getattr(item, "_fixtureinfo", None), "name2fixturedefs", {}).items():
        if name == "_unit_stays_in_process":
            continue
        for fixturedef in defs:
            reached |= _reaches(fixturedef.func, seen)
    base = item.nodeid.split("[", 1)[0]
    if "browser" in fixtures:
        tier = "browser"
    elif "live" in reached or base in INTEGRATION:
        tier = "integration"
    elif base in SLOW:
        tier = "slow"
    else:
        tier = "unit"
    return tier, reached


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(config, items):
    for item in items:
        tier, reached = _tier_of(item)
        item.add_marker(getattr(pytest.mark, tier))
        if "recording" in reached and item.get_closest_marker("recording") is None:
            item.add_marker(pytest.mark.recording)
        if _listed(item, SERIAL):
            item.add_marker(pytest.mark.serial)
        elif lane := _listed(item, REALTIME):
            item.add_marker(pytest.mark.xdist_group(lane[0]))
        elif _listed(item, SHARED_SETUP):
            item.add_marker(pytest.mark.xdist_group(Path(item.nodeid.split("::", 1)[0]).stem))


class XdistGroups:
    """``--dist loadgroup`` sends the tests of an ``xdist_group`` to one worker by the ``@group``
    suffix pytest-xdist (3.8) adds to each nodeid in the workers, through ``item._nodeid``; pytest
    9.2 builds the nodeid from ``item._id`` instead, so the suffix was lost and every group ran
    over both workers (CI at 7fd9de3: test_faults.py on gw1 beside test_faults_tls.py on gw0).
    Where xdist's suffix did not take, it is added here, after xdist's hook."""

    @pytest.hookimpl(trylast=True)
    def pytest_collection_modifyitems(self, config, items):
        if not getattr(config.option, "loadgroup", False):
            return
        for item in items:
            names = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                            for m in item.iter_markers("xdist_group")})
            nodeid = item.nodeid
            if names and nodeid.rfind("@") <= nodeid.rfind("]") and hasattr(item, "_id"):
                from _pytest.nodeid import NodeId

                item._id = NodeId.parse(f"{nodeid}@{'_'.join(names)}")


def pytest_configure(config):
    config.pluginmanager.register(XdistGroups(), "firetrack-xdist-groups")


# The programs a unit test must not start: the project's own processes (a Python child, the
# firetrack command), a router, a browser. A library's helper (matplotlib's fc-list when it
# builds its font cache) is not refused.
_PROCESSES = (sys.executable, "python", "firetrack", "zenohd", "chromium", "lint-imports")


@pytest.fixture(autouse=True)
def _unit_stays_in_process(request, monkeypatch):
    """A unit test must not open a zenoh session nor start one of the project's processes: if
    one does, the tiering above missed it, and the test fails saying so."""
    if request.node.get_closest_marker("unit") is None:
        yield
        return
    import multiprocessing.process
    import subprocess

    import zenoh

    def refuse(what):
        raise AssertionError(f"{request.node.nodeid} is tiered unit but {what}: add it to INTEGRATION in "
                             "tests/conftest.py with the reason")

    popen = subprocess.Popen

    def checked_popen(args, *rest, **kwargs):
        argv = [args] if isinstance(args, (str, bytes, os.PathLike)) else list(args)
        if any(p in str(a) for a in argv[:4] for p in _PROCESSES):
            refuse(f"starts {' '.join(map(str, argv[:3]))}")
        return popen(args, *rest, **kwargs)

    monkeypatch.setattr(zenoh, "open", lambda *a, **k: refuse("opens a zenoh session"))
    monkeypatch.setattr(subprocess, "Popen", checked_popen)
    monkeypatch.setattr(multiprocessing.process.BaseProcess, "start", lambda self: refuse("starts a process"))
    yield


_CPU_LOG = os.environ.get("FIRETRACK_TEST_CPU")
if _CPU_LOG:
    import time as _time  # noqa: E402

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        """Each test's CPU seconds in this process (not its children), appended to the file."""
        t0 = _time.process_time()
        yield
        with open(_CPU_LOG, "a") as f:
            f.write(f"{_time.process_time() - t0:.3f}\t{item.nodeid}\n")

"""``firetrack reprocess`` and ``firetrack exercise``: after-action review of recorded incidents."""
from __future__ import annotations

import json
import math
from pathlib import Path

import typer
from rich.table import Table

from service.protocol.terminal import err, fail, out, print_json, warn


def _cfg(config: Path | None):
    from service.protocol.incident import (
        IncidentConfigError,
        default_incident,
        load_incident,
    )

    try:
        return load_incident(config) if config else default_incident()
    except IncidentConfigError as e:
        fail(str(e))
        raise typer.Exit(2)


def reprocess_command(
    file: Path = typer.Argument(..., help="an incident recording (.mcap) from serve --record, record or exercise"),
    config: Path = typer.Option(None, "--config", help="incident config (default: the IPIN museum demo)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON"),
    export: Path = typer.Option(None, "--export", help="write the tracks here: tracks.geojson, tracks.csv, <responder>.tum "
                                                        "(smoothed), live.csv (the live poses with their covariance), "
                                                        "tracks.kml (Google Earth, live and smoothed) and foxglove.mcap "
                                                        "(Foxglove; needs the [foxglove] extra)"),
    accept_damaged: bool = typer.Option(False, "--accept-damaged", help="a recording cut or corrupt somewhere (a "
                                        "crash, a bad disk) is reprocessed as far as it reads, and the exit code is 0"),
):
    """Run the service pipeline offline over the recorded inputs and compare with the poses recorded live.

    A recording that is cut off or has a corrupt chunk (CRC) is read as far as it can be; each
    place is named with its byte offset, and the exit code is 1 unless ``--accept-damaged``."""
    from service.review.recording_reader import TruncatedRecordingWarning
    from service.review.reprocess import reprocess

    if not file.is_file():
        fail(f"{file}: no such recording")
        raise typer.Exit(2)
    cfg = _cfg(config)
    import warnings

    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rep = reprocess(file, cfg)
    except (ValueError, OSError) as e:
        fail(str(e))
        raise typer.Exit(1)
    for w in caught:  # one clear line, not a Python warning
        if not issubclass(w.category, TruncatedRecordingWarning):  # the damage is said below
            warn(str(w.message))
    for d in rep["damage"]:
        (warn if accept_damaged else fail)(f"{d['file']}: {d['problem']}")
    tracks = rep.pop("tracks")
    live = rep.pop("live_tracks")
    events = rep.pop("events")
    rep["events"] = len(events)
    if rep["errors"]:
        fail(f"{file}: {rep['errors']} message(s) raised an error while reprocessing (see the log above); "
             "the other messages were processed")
    if export is not None:
        try:
            _export(tracks, cfg, export, live, events)
        except (ValueError, OSError) as e:
            fail(f"export to {export}: {e}")
            raise typer.Exit(1)
    if as_json:
        print_json({k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in rep.items()})
    else:
        _print_table(file, rep)
    if rep["damage"] and not accept_damaged:
        fail(f"{file}: damaged in {len(rep['damage'])} place(s); {rep['inputs']} inputs were read and reprocessed. "
             "A recording cut by a crash ends like this: pass --accept-damaged to take what was read")
        raise typer.Exit(1)


def _print_table(file: Path, rep: dict) -> None:
    table = Table(title=f"reprocessed {file.name}: {rep['inputs']} inputs in {rep['cpu_s']:.2f} s CPU"
                        + (f" ({rep['realtime_factor']:.0f}x real time)" if rep["realtime_factor"] else ""))
    for col in ("responder", "steps", "live track m", "smoothed track m", "poses", "recorded", "max deviation m"):
        table.add_column(col, justify="left" if col == "responder" else "right")
    for rid, r in rep["responders"].items():
        dev = r["max_deviation_m"]
        smoothed = r["distance_smoothed_m"]
        table.add_row(rid, str(r["steps"]), f"{r['distance_live_m']:.1f}", "—" if smoothed is None else f"{smoothed:.1f}",
                      str(r["poses"]), str(r["recorded_poses"]),
                      "—" if dev is None else f"{dev:.3g}")
    out.print(table)


def _export(tracks: dict, cfg, folder: Path, live: dict | None = None, events: list | None = None) -> None:
    from pdr.floors import FloorElevations
    from service.review.export import to_csv, to_geojson, to_tum
    from service.review.kml import write_kml

    folder.mkdir(parents=True, exist_ok=True)
    origin = (cfg.origin.lat, cfg.origin.lon, cfg.origin.alt_m)
    floors = FloorElevations(cfg.elevations())
    (folder / "tracks.geojson").write_text(json.dumps(to_geojson(tracks, origin, floors)))
    to_csv(tracks, folder / "tracks.csv", origin, floors)
    for rid, tr in tracks.items():
        to_tum(tr, folder / f"{rid}.tum", floors)
    if live:  # the smoother keeps no covariance in hindsight; the live poses carry the one the console showed
        to_csv(live, folder / "live.csv", origin, floors)
    skipped = write_kml(tracks, folder / "tracks.kml", origin, floors, live=live, name=f"{cfg.id}: {cfg.name}")
    if skipped:
        warn(f"tracks.kml leaves out {', '.join(skipped)}: no UTC time known for them")
    err.print(f"wrote {len(tracks)} smoothed track(s) to {folder}/ (tracks.geojson, tracks.csv, <responder>.tum, tracks.kml)"
              + (f" and {len(live)} live track(s) with covariance (live.csv)" if live else ""))
    try:
        from service.review.foxglove_export import write_foxglove_mcap
    except ImportError:
        warn("foxglove.mcap not written: the Foxglove export needs the foxglove extra (pip install 'firetrack\\[foxglove]')")
        return
    counts = write_foxglove_mcap(folder / "foxglove.mcap", cfg, live or {}, tracks, events or [])
    err.print(f"wrote {folder}/foxglove.mcap: {sum(counts.values())} messages on {len(counts)} topics (open it in Foxglove)")


def exercise_command(
    responder: list[str] = typer.Option(..., "--responder", help="ID=FILE: responder ID walks recording FILE; repeat"),
    out_file: Path = typer.Option(..., "--out", help="the exercise recording to write (.mcap)"),
    config: Path = typer.Option(None, "--config", help="incident config (default: the IPIN museum demo)"),
    landmark_every: int = typer.Option(0, "--landmark-every", help="also send every K-th landmark as a checkpoint fix"),
    gnss: bool = typer.Option(True, "--gnss/--no-gnss", help="include the recordings' GNSS fixes"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing file"),
):
    """Combine single-person recordings into one multi-person exercise with aligned start times."""
    from pdr.io.errors import RecordingFormatError
    from service.review.reprocess import build_exercise

    members = []
    for item in responder:
        rid, sep, path = item.partition("=")
        if not sep or not rid or not path:
            fail(f"--responder expects ID=FILE, got {item!r}")
            raise typer.Exit(2)
        members.append((rid, Path(path)))
    try:
        result = build_exercise(members, out_file, _cfg(config), landmark_every=landmark_every, gnss=gnss,
                                overwrite=overwrite)
    except (RecordingFormatError, OSError, ValueError) as e:
        fail(str(e))
        raise typer.Exit(1)
    out.print(f"wrote {result['file']}: {len(result['responders'])} responders, {result['duration_s']:.0f} s")

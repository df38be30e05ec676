"""``firetrack eval ble``: confront a beacon survey with walks that have ground truth
(:mod:`service.review.ble_survey`): where each beacon is heard strongest, whether its listed
identity, position and floor agree, and the pairing (and calibrated tx power) the data suggest."""
from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.table import Table

from service.cli.eval_ipin import walk_files
from service.cli.recordings import load_all
from service.protocol.terminal import fail, out, print_json


def eval_ble(
    files: list[Path] = typer.Argument(..., help="walks with landmarks and BLE4 lines (GetSensorData logs)"),
    survey: Path = typer.Option(..., "--survey", help="the survey: CSV with bleID, Lat, Lon, floor (e.g. BLE_Locations.csv)"),
    incident: Path = typer.Option(None, "--incident", help="incident config (its origin); default: the IPIN museum demo"),
    tolerance: float = typer.Option(5.0, "--tolerance", help="m: a position agrees when the beacon is heard strongest this close to it"),
    exponent: float = typer.Option(None, "--exponent", help="path-loss exponent n for the tx power fit (default: the fusion's)"),
    config: Path = typer.Option(None, "--config", help="write the suggested 'beacons' list (JSON) to this file"),
    as_json: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
):
    """Per beacon: readings, where heard strongest, the listed and the matched survey entry, agreement, fitted tx power."""
    from service.fusion.fixes.ble import BleSettings
    from service.protocol.incident import IncidentConfigError, default_incident, load_incident
    from service.review.ble_survey import as_dicts, check_survey, config_beacons, read_survey

    try:
        cfg = load_incident(incident) if incident else default_incident()
        entries = read_survey(survey, cfg)
    except (IncidentConfigError, ValueError) as e:
        fail(str(e))
        raise typer.Exit(2)
    walks, _ = walk_files(files)
    recordings, bad = load_all(walks)
    recordings = [r for r in recordings if r.ble is not None and r.landmarks is not None and len(r.landmarks) > 1]
    if not recordings:
        fail("no walk with landmarks and beacon readings")
        raise typer.Exit(2)
    n = exponent if exponent is not None else BleSettings().path_loss_exponent
    checks = check_survey(recordings, entries, cfg, path_loss_exponent=n, position_tolerance_m=tolerance)
    suggested = config_beacons(checks, entries)
    if config is not None:
        config.write_text(json.dumps(suggested, indent=1) + "\n", encoding="utf-8")
    if as_json:
        print_json({"walks": len(recordings), "path_loss_exponent": n, "tolerance_m": tolerance,
                    "beacons": as_dicts(checks), "suggested_config": suggested})
    else:
        out.print(_table(checks, len(recordings)))
    if bad:
        raise typer.Exit(1)


def _table(checks, walks: int) -> Table:
    t = Table(title=f"survey check on {walks} walks: where each beacon is heard strongest")
    for col in ("beacon", "n", "max dBm", "heard at x, y, floor", "listed (m)", "matched (m)", "P₀ dBm"):
        t.add_column(col, no_wrap=True)
    t.add_column("verdict")
    for c in checks:
        f = (lambda v: "—" if v is None else f"{v:.1f}")
        t.add_row(c.beacon, str(c.readings), f"{c.strongest_rssi_dbm:.0f}", f"{c.heard_x:.1f}, {c.heard_y:.1f}, {c.heard_floor}",
                  f"{c.listed or '—'} ({f(c.listed_distance_m)})", f"{c.matched or '—'} ({f(c.matched_distance_m)})",
                  f(c.tx_power_dbm), c.verdict())
    return t

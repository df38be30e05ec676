"""Loading the recordings named on a command line: each bad file reported, the others go on."""
from __future__ import annotations

import warnings
from pathlib import Path

from pdr.io import load
from pdr.io.errors import RecordingFormatError, RecordingWarning
from service.protocol.terminal import fail, progress, warn


def load_all(files: list[Path]):
    """Load each file; a bad one is reported and skipped, the others go on."""
    warnings.simplefilter("ignore", RecordingWarning)  # each is printed once below
    loaded, bad = [], 0
    for path in progress(files, "loading"):
        try:
            rec = load(path)
        except (RecordingFormatError, OSError) as e:
            fail(str(e))
            bad += 1
            continue
        for w in rec.warnings:
            warn(f"{path}: {w}")
        loaded.append(rec)
    return loaded, bad

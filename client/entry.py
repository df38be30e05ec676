"""The ``firetrack`` console script: Ctrl-C at any moment ends it cleanly.

The command's modules take a second or two to import (numpy, zenoh, gtsam); a Ctrl-C in that
time would otherwise end in a traceback. Everything is imported inside the ``try`` here.
"""
from __future__ import annotations

import sys


def main() -> None:
    try:
        from client.cli import main as run

        run()
    except BaseException as e:  # noqa: BLE001 - only to tell an interrupt from a failure
        if not _interrupted(e):
            raise
        sys.stderr.write("\ninterrupted\n")
        raise SystemExit(130) from None


def _interrupted(e: BaseException | None) -> bool:
    """A Ctrl-C, or an error raised because of one (an extension module whose initialisation
    was interrupted reports ImportError, with the KeyboardInterrupt as its cause)."""
    seen = 0
    while e is not None and seen < 10:
        if isinstance(e, KeyboardInterrupt):
            return True
        e, seen = e.__cause__ or e.__context__, seen + 1
    return False


if __name__ == "__main__":
    main()

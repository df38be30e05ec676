"""The ``firetrack`` console script: Ctrl-C at any moment ends it cleanly, and so does the end
of any command, however many zenoh sessions and wearables it held.

The command's modules take a second or two to import (numpy, zenoh, gtsam); a Ctrl-C in that
time would otherwise end in a traceback. Everything is imported inside the ``try`` here. A
command that returns leaves through :func:`service.protocol.terminal.leave_process`, which
does not finalise the interpreter under zenoh's threads (why: its docstring).
"""
from __future__ import annotations

import sys
import traceback


def main() -> None:
    code = _run()
    try:
        from service.protocol.terminal import leave_process
    except BaseException:  # noqa: BLE001 - interrupted while importing: the ordinary exit
        raise SystemExit(code) from None
    leave_process(code)


def _run(command=None) -> int:
    """Run the command (``command``: the CLI by default); its exit code (130 after Ctrl-C, 1
    after an uncaught error, printed)."""
    try:
        from service.protocol.early_interrupt import remember_interrupts

        remember_interrupts()  # before the seconds of imports (why: that module's docstring)
        if command is None:
            from client.cli import main as command
        command()
        return 0
    except SystemExit as e:
        code = _exit_code(e.code)
        if code == 130:  # typer ends a KeyboardInterrupt as a silent exit 130: say why it ended
            sys.stderr.write("\ninterrupted\n")
        return code
    except BaseException as e:  # noqa: BLE001 - only to tell an interrupt from a failure
        if not _interrupted(e):
            traceback.print_exc()
            return 1
        sys.stderr.write("\ninterrupted\n")
        return 130


def _exit_code(code) -> int:
    """``SystemExit.code`` as the process's exit status (a message is printed, status 1)."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    sys.stderr.write(f"{code}\n")
    return 1


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

"""A Ctrl-C that came before a command's own handler, remembered.

From the moment the ``firetrack`` script starts until a long-running command installs its stop
handler (:func:`service.protocol.terminal.stop_on_signals`) the modules take seconds to import.
A Ctrl-C then raises ``KeyboardInterrupt`` wherever the main thread is, and a library that
guards an optional import with ``except ImportError`` (an interrupted extension module reports
ImportError, the interrupt as its cause) or a broad ``except`` can swallow it. The command
then starts as if nothing had been pressed: CI saw ``firetrack serve`` print "serving" after
a Ctrl-C 0.3 s and 1.0 s into its start, and keep serving. So the first handler both raises
(the interrupt ends the command where nothing swallows it) and remembers; the stop handler
treats a remembered Ctrl-C as its own. Deliberately free of imports beyond ``signal``.
"""
from __future__ import annotations

import signal

_seen: list[int] = []


def remember_interrupts() -> None:
    """SIGINT raises ``KeyboardInterrupt`` as by default, and is remembered."""

    def handler(signum, frame):
        _seen.append(signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, handler)


def interrupted_early() -> bool:
    """Was there a Ctrl-C before the command's own handler? (It was swallowed if we got here.)"""
    return bool(_seen)

"""What a running process uses, read from Linux's /proc (the benches measure their children
with it); NaN where /proc cannot say (another OS, a process gone)."""
from __future__ import annotations

import math
import os
from pathlib import Path


def rss_mb(pid: int, field: str = "VmRSS") -> float:
    """The process's resident memory (MB): ``VmRSS`` in all, or ``RssAnon``, the part that is
    the process's own (heap, stacks) and not pages of mapped files such as the libraries' code,
    which the first use of a code path (a flood's error paths in zenoh's 33 MB library) brings
    in and the kernel may drop again at any time."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


def cpu_s(pid: int) -> float:
    """CPU time (user + system, s) the process has used, all its threads (zenoh's too)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return math.nan

"""Resident memory of this process and of other processes, for benchmarks.

Not getrusage's ru_maxrss: Linux carries a process's high-water mark across exec (fs/exec.c keeps the larger of
the old and new mm's in signal->maxrss), so a child started by subprocess (fork, then exec) reports at least its
parent's resident size at the fork; under `python -m bench`, after the 100k-row identify case, that was 934 MB
for every planning case. VmHWM of /proc/PID/status is the peak of that process image alone (proc(5)).

A forked child's resident size counts the pages it still shares with its parent; its own pages, what it adds to
the machine, are the private ones of /proc/PID/smaps_rollup (Private_Clean + Private_Dirty, proc(5))."""

from __future__ import annotations

import os
from pathlib import Path


def _status_mb(pid: int | str, field: str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) / 1024  # kB
    raise RuntimeError(f"no {field} in /proc/{pid}/status (memory is measured on Linux only)")


def peak_rss_mb(pid: int | str = "self") -> float:
    """The peak resident memory of a process (VmHWM), MB."""
    return _status_mb(pid, "VmHWM")


def rss_mb(pid: int | str = "self") -> float:
    """The resident memory of a process now (VmRSS), MB."""
    return _status_mb(pid, "VmRSS")


def private_mb(pid: int | str = "self") -> float:
    """The resident memory a process shares with no other (Private_Clean + Private_Dirty), MB."""
    kb = 0
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        if line.startswith(("Private_Clean:", "Private_Dirty:")):
            kb += int(line.split()[1])
    return kb / 1024


def children(pid: int | None = None) -> list[int]:
    """The processes whose parent is `pid` (default: this process), from /proc/*/stat."""
    pid = os.getpid() if pid is None else pid
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:  # ended between the listing and the read
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:  # the field after the state (proc(5)); comm may hold ')'
            out.append(int(d.name))
    return out

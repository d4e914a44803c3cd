"""What the machine can hold: a count a user types (poses, configurations, starts, repetitions) is refused in one
line that says the limit, before a job allocates memory for it.

A job estimates the bytes its options need from measured bytes per item (the constants live with each job) and
`check_memory` compares them with the memory this process can still get: the kernel's MemAvailable, capped by
the control group's limit (a container's), never more than MEMORY_CEILING_BYTES.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from trackcal.calib.io.table import MAX_CELLS, joint_columns
from trackcal.campaign.errors import OptionError

GIB = 2.0**30
# a fixed ceiling whatever the machine says (a job near it would run for hours: simulate measures ~60 poses/s)
MEMORY_CEILING_BYTES = 64 * 2**30


def meminfo_available() -> int | None:
    """MemAvailable of /proc/meminfo (Linux: free memory plus what the page cache can give back), bytes."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def cgroup_available() -> int | None:
    """What the cgroup v2 limit leaves (memory.max - memory.current), bytes; None without a limit."""
    root = Path("/sys/fs/cgroup")
    try:
        limit = (root / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return max(0, int(limit) - int((root / "memory.current").read_text()))
    except (OSError, ValueError):
        return None


def available_bytes() -> int:
    """Memory this process can still allocate: the least of MemAvailable (else the free pages os.sysconf gives),
    the cgroup's limit and MEMORY_CEILING_BYTES."""
    known = [meminfo_available(), cgroup_available(), MEMORY_CEILING_BYTES]
    if known[0] is None:
        try:
            known[0] = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            known[0] = None
    return min(v for v in known if v is not None)


def check_memory(option: str, count: int, need: Callable[[int], float], what: str) -> None:
    """Refuse `option` = `count` when the job would need more memory than is available (`need(n)`: bytes with the
    option at n, the others as given): one line with the need, what is available and the largest count that
    fits (by bisection: a need may grow faster than the count)."""
    available = available_bytes()
    needed = need(count)
    if needed <= available:
        return
    low, high = 0, count  # need(low) fits (or low is 0), need(high) does not
    while high - low > 1:
        mid = (low + high) // 2
        low, high = (mid, high) if need(mid) <= available else (low, mid)
    raise OptionError(
        "{0} {count}: needs about {need:.1f} GiB of memory ({each} per {what}), {avail:.1f} GiB is "
        "available: at most {most}",
        option,
        count=count,
        need=needed / GIB,
        each=readable(needed / count),
        what=what,
        avail=available / GIB,
        most=low,
    )


def table_rows_allowed(dof: int) -> int:
    """The rows a measurement table of a `dof`-joint robot may hold (calib.io.table reads at most MAX_CELLS cells)."""
    columns = 5 + len(joint_columns(dof)) + 3  # seq, t_s, pose, station, point, the joints, x, y, z
    return MAX_CELLS // columns


def check_table_rows(option: str, count: int, rows: int, dof: int, what: str) -> None:
    """Refuse `option` = `count` when its campaign's table (`rows` measurements) could not be read back: a table
    trackcal cannot identify is no campaign."""
    allowed = table_rows_allowed(dof)
    if rows > allowed:
        raise OptionError(
            "{0} {count}: the campaign would measure {rows} rows, more than the {allowed} a "
            "measurement table may hold ({cells} cells): at most {most} {what}",
            option,
            count=count,
            rows=rows,
            allowed=allowed,
            cells=MAX_CELLS,
            most=allowed * count // rows,
            what=what,
        )


def readable(n: float) -> str:
    for unit, size in (("GiB", GIB), ("MiB", 2.0**20), ("KiB", 2.0**10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n:.0f} bytes"

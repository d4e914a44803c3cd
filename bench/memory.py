"""Peak resident memory of this process, for benchmarks that run a case in a fresh subprocess.

Not getrusage's ru_maxrss: Linux carries a process's high-water mark across exec (fs/exec.c keeps the larger of
the old and new mm's in signal->maxrss), so a child started by subprocess (fork, then exec) reports at least its
parent's resident size at the fork; under `python -m bench`, after the 100k-row identify case, that was 934 MB
for every planning case. VmHWM of /proc/self/status is the peak of this process image alone (proc(5))."""

from __future__ import annotations

from pathlib import Path


def peak_rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024  # kB
    raise RuntimeError("no VmHWM in /proc/self/status (peak memory is measured on Linux only)")

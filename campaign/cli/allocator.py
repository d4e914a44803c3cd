"""The C allocator of a trackcal process: freed blocks of up to 32 MB are kept for the arrays that follow.

glibc's malloc serves a block above its mmap threshold with pages of its own, given back when the block is freed, and
gives back the top of its heap beyond its trim threshold. Both move with the blocks freed (the mmap threshold from
128 KB up to 32 MB, the trim threshold twice it), so a process that makes and frees thousands of arrays of 1-10 MB
(a diagnosis: its folds' Jacobian rows, Gram matrices and Schur complements) has many of them faulted in again, page
by page, each page zeroed by the kernel. Issue 41, `trackcal diagnose` of the UR10's Series B: 79,000 minor page
faults and 3.64 s CPU with glibc's moving thresholds, 47,000 and 3.36 s with them fixed at 32 MB and 64 MB, peak
resident memory 277 -> 296 MB (one run each, /usr/bin/time).

Set once, when a command starts (`campaign.cli.main`), where the C library is glibc (`mallopt`, glibc's malloc.h);
elsewhere nothing changes.
"""

from __future__ import annotations

import ctypes
import os

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc's malloc.h
MMAP_THRESHOLD = 32 * 2**20  # glibc's largest moving mmap threshold on 64-bit (DEFAULT_MMAP_THRESHOLD_MAX)
TRIM_THRESHOLD = 2 * MMAP_THRESHOLD  # what glibc makes it when the mmap threshold reaches that


def glibc() -> bool:
    try:
        return os.confstr("CS_GNU_LIBC_VERSION").startswith("glibc")
    except (ValueError, OSError):  # not a GNU C library: the name is unknown to confstr
        return False


def keep_freed_blocks() -> bool:
    """Fix glibc's mmap and trim thresholds at MMAP_THRESHOLD and TRIM_THRESHOLD; False where the C library is not
    glibc (nothing done)."""
    if not glibc():
        return False
    libc = ctypes.CDLL(None)  # the process's own C library
    return bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))

"""issue 41: a command keeps freed blocks of up to 32 MB for the arrays that follow (`campaign.cli.allocator`), where
glibc's moving thresholds gave them back and had them faulted in again, page by page."""

import subprocess
import sys

import pytest

from trackcal.campaign.cli.allocator import glibc

# A fresh interpreter makes an 8 MB array, frees it and makes another: the page faults of the second. With glibc's
# moving thresholds the first is mapped on its own and given back; the second, below the raised mmap threshold, grows
# the heap, whose new pages are faulted in (505 faults on the 2026 CI machine, a fault mapping several 4 KB pages).
# With the thresholds fixed the first stays in the heap when freed and the second reuses its pages (0 faults).
CHILD = """
import resource, sys
import numpy as np
from trackcal.campaign.cli.allocator import keep_freed_blocks
if sys.argv[1] == "kept":
    assert keep_freed_blocks()
np.ones(2**20)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
np.ones(2**20)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not glibc(), reason="mallopt is glibc's")
def test_a_freed_array_is_reused_without_page_faults():
    faults = {
        how: int(subprocess.run([sys.executable, "-c", CHILD, how], capture_output=True, check=True, text=True).stdout)
        for how in ("moving", "kept")
    }
    assert faults["moving"] >= 2**23 // 2**21  # at least one fault per page, were they 2 MB huge pages
    assert faults["kept"] <= faults["moving"] // 10

"""`python -m bench` (make bench): run every benchmark module in this folder, on one BLAS thread as every
trackcal command runs (TRACKCAL_BLAS_THREADS changes both)."""

import importlib
import pkgutil
from pathlib import Path

from bench.goals import summary
from trackcal.campaign.cli.blas import limited_blas

MODULES = sorted(m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)]) if m.name.startswith("bench_"))
with limited_blas():
    for mod in MODULES:
        print(f"== {mod}", flush=True)
        importlib.import_module(f"bench.{mod}").main()
print(summary())

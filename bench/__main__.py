"""`python -m bench` (make bench): run every benchmark module in this folder."""

import importlib
import pkgutil
from pathlib import Path

for mod in sorted(m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)]) if m.name.startswith("bench_")):
    print(f"== {mod}")
    importlib.import_module(f"bench.{mod}").main()

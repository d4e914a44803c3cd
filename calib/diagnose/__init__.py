"""Model discovery beyond the geometric model: `diagnose` (`calib.diagnose.diagnosis`).

The package's modules are imported by those that need them: `identify` and the model file read the extensions
(calib.diagnose.extensions) without the search, so importing one of them does not import the whole diagnosis
(issue 41: a 100-row identify's start-up). `from trackcal.calib.diagnose import diagnose` still works.
"""

from __future__ import annotations

import importlib

__all__ = ["Diagnosis", "diagnose"]


def __getattr__(name: str):
    """`Diagnosis` and `diagnose` from calib.diagnose.diagnosis, imported when first asked for (PEP 562)."""
    if name in __all__:
        return getattr(importlib.import_module("trackcal.calib.diagnose.diagnosis"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

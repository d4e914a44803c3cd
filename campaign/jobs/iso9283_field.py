"""The tracker's field check of an ISO 9283 session: a known length between two tool points (their distance
certified, e.g. measured on a CMM), each measured with the robot standing at P1, before the test.

The check is the length measurement test of ASME B89.4.19-2006 / ISO 10360-10 done once in the field: the tracker's
measured length against the certified one, within the tracker's MPE (calib.model.instruments: Leica states the MPE
of a point as A um + B um/m of range, per ASME B89.4.19). The MPE is the hardware file's (tracker.mpe_um,
tracker.mpe_um_per_m: the tracker's certificate) where it states one, else the datasheet's of the cell's tracker
model; the range is the farther point's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.model.instruments import Instrument

PASS, FAIL = "pass", "fail"


@dataclass(frozen=True)
class FieldCheck:
    points: tuple[str, str]
    certified_mm: float
    measured_mm: float
    mpe_mm: float
    mpe_source: str

    @property
    def error_mm(self) -> float:
        return self.measured_mm - self.certified_mm

    @property
    def verdict(self) -> str:
        return PASS if abs(self.error_mm) <= self.mpe_mm else FAIL

    def describe(self) -> str:
        a, b = self.points
        return (
            f"length {a}-{b}: measured {self.measured_mm:.4f} mm, certified {self.certified_mm:.4f} mm, error "
            f"{self.error_mm * 1000:+.1f} µm, MPE ±{self.mpe_mm * 1000:.1f} µm ({self.mpe_source}): "
            f"{self.verdict} (ASME B89.4.19 / ISO 10360-10 length check)"
        )


def mpe_mm(range_m: float, tracker: dict | None, instrument: Instrument) -> tuple[float, str]:
    """The tracker's MPE at `range_m` and where it comes from: the hardware file's, else the datasheet's (the point
    MPE, twice the instrument's transverse sigma: calib.model.instruments reads MPE as 2 sigma)."""
    t = tracker or {}
    if t.get("mpe_um") is not None:
        a, b = float(t["mpe_um"]), float(t.get("mpe_um_per_m") or 0.0)
        return (a + b * range_m) / 1000.0, f"{a:g} µm + {b:g} µm/m, the hardware file"
    a, b = 2 * instrument.transverse_mm * 1000, 2 * instrument.transverse_mm_per_m * 1000
    return (a + b * range_m) / 1000.0, f"{a:g} µm + {b:g} µm/m, the {instrument.name} datasheet"


def field_check(
    block: dict, rows: dict[str, np.ndarray], tracker: dict | None, instrument: Instrument
) -> FieldCheck | None:
    """The check from the plan's `field_check` block and the measured positions (station frame, mm) of each of its
    points (the mean of that point's field-check measurements); None when a point was not measured."""
    a, b = block["points"]
    if len(rows.get(a, [])) == 0 or len(rows.get(b, [])) == 0:
        return None
    xa, xb = np.mean(rows[a], axis=0), np.mean(rows[b], axis=0)
    limit, source = mpe_mm(max(np.linalg.norm(xa), np.linalg.norm(xb)) / 1000.0, tracker, instrument)
    return FieldCheck((a, b), float(block["length_mm"]), float(np.linalg.norm(xa - xb)), limit, source)

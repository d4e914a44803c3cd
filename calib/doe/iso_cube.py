"""The ISO 9283 test cube and its five poses (ISO 9283:1998, 6.7: location of the cube, poses to be used).

The cube has its edges parallel to the base frame and the largest volume the usable workspace allows; the poses
lie on the diagonal plane C1-C2-C7-C8, the rectangle through two opposite edges of the cube: P1 at the centre of
the cube, P2..P5 on the plane's two diagonals at 10 % of the diagonal length L from the corners (the standard
allows 10 +- 2 %). trackcal numbers the corners so that C1-C2 is the lower front edge and C7-C8 the upper back edge
(C1 = min x, min y, min z; C2 = max x, min y, min z; C7 = max x, max y, max z; C8 = min x, max y, max z); P2, P3,
P4, P5 are the poses near C1, C2, C7, C8. The plane's diagonals are the cube's space diagonals, L = side * sqrt(3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.errors import CalibError

CORNER_FRACTION = 0.10  # ISO 9283:1998, 6.7: P2..P5 at (10 +- 2) % of the diagonal from the corners
# One test cycle visits P1, P5, P4, P3, P2 (ISO 9283:1998, 7.2.1), each approached in the same direction.
CYCLE_ORDER = (0, 4, 3, 2, 1)


class CubeError(CalibError):
    """A cube that does not fit the cell or is not a cube."""


@dataclass(frozen=True)
class IsoCube:
    centre_mm: tuple[float, float, float]
    side_mm: float

    def __post_init__(self):
        if not (np.isfinite(self.side_mm) and self.side_mm > 0) or not np.isfinite(self.centre_mm).all():
            raise CubeError(f"ISO cube: side {self.side_mm!r} mm, centre {self.centre_mm!r}: finite, side > 0 needed")

    @property
    def diagonal_mm(self) -> float:
        """L, the diagonal of the plane C1-C2-C7-C8 (a space diagonal of the cube)."""
        return self.side_mm * float(np.sqrt(3.0))

    def corners(self) -> np.ndarray:
        """C1..C8, (8, 3): C1..C4 the lower face (z min), C5..C8 the upper face, numbered as the module says."""
        lo = np.asarray(self.centre_mm, float) - self.side_mm / 2
        s = self.side_mm
        unit = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
        return lo + s * unit

    def plane_corners(self) -> np.ndarray:
        """C1, C2, C7, C8: the corners of the measuring plane, (4, 3)."""
        return self.corners()[[0, 1, 6, 7]]

    def poses(self, fraction: float = CORNER_FRACTION) -> np.ndarray:
        """P1..P5, (5, 3): the centre, then a point on each plane diagonal `fraction` of L from C1, C2, C7, C8."""
        if not 0.08 <= fraction <= 0.12:
            raise CubeError(f"ISO cube: poses at {fraction:.0%} of the diagonal; the standard allows 8-12 %")
        c = np.asarray(self.centre_mm, float)
        near = self.plane_corners()
        return np.vstack([c, near + fraction * 2.0 * (c - near)])


def largest_cube(box_min, box_max, centre=None) -> IsoCube:
    """The largest cube with edges parallel to the base frame inside the box [box_min, box_max] (the cell's box),
    centred on `centre` (default the box's centre)."""
    lo, hi = np.asarray(box_min, float), np.asarray(box_max, float)
    if lo.shape != (3,) or hi.shape != (3,) or not (hi > lo).all():
        raise CubeError(f"ISO cube: the box {lo.tolist()} .. {hi.tolist()} is empty")
    c = (lo + hi) / 2 if centre is None else np.asarray(centre, float)
    if c.shape != (3,) or not ((c > lo) & (c < hi)).all():
        raise CubeError(f"ISO cube: the centre {np.asarray(centre).tolist()} is not inside the box")
    half = float(np.min(np.minimum(c - lo, hi - c)))
    return IsoCube(tuple(float(v) for v in c), 2.0 * half)

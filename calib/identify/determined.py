"""Which parameters does a table determine? Each parameter's 95 % interval against its effect at the noise floor.

A parameter whose interval is wide in millimetres may still be well determined (a short lever moves the points
little), and one with a narrow interval may be fixed only through its correlation with others. The measure here is
in the units of the measurements: move the parameter alone by its 95 % half-width; by how many noise floors (RMS per
coordinate over the table's rows) do the measured reflectors move? With J the whitened Jacobian of the fit (columns
of every unknown: parameters, extension, stations, points; the noise model's unit noise) and J_p the parameter's
column, that is

    ratio_p = 1.96 sqrt((J^T J)^-1_pp) * rms(J_p)

It does not depend on the scale of the noise (both factors scale with it). A parameter with no correlation reaches
1.96 / sqrt(3N); an ordinary fit of the README's 30-pose KR-270 campaign (69 rows, 18 irreducible parameters)
reaches 0.2-1.5. Above POORLY_DETERMINED the table fixes the parameter only by a near-dependence on the other
unknowns: its interval spans ten noise floors' worth of displacement that other unknowns take back, and its value
is whatever the noise makes it (issue 25: px5 +-44.9 mm and phix5 +-27.4 deg on the UR10 with its one reference point
on the wrist_3 axis).
"""

from __future__ import annotations

import numpy as np

# An order of magnitude above the noise floor; ordinary fits stay below 1.5 (module docstring).
POORLY_DETERMINED = 10.0


def noise_floor_ratios(jm: np.ndarray, cols: np.ndarray | list[int], n_eq: int | None = None) -> np.ndarray:
    """ratio_p (module docstring) of the columns `cols` of the whitened Jacobian `jm` (3N, m) of a fit; inf for a
    column the others make singular. `jm` may be any matrix with the Jacobian's column products, its R factor
    (J = QR: column norms, Gram matrix and least-squares residuals between columns are R's), with `n_eq` the
    Jacobian's rows, 3N (default: jm's)."""
    cols = np.asarray(cols, dtype=int)
    n_eq = jm.shape[0] if n_eq is None else n_eq
    scale = np.linalg.norm(jm, axis=0)
    scale[scale == 0] = 1.0
    js = jm / scale
    gram = js.T @ js
    out = np.full(len(cols), np.inf)
    ev_min = np.linalg.eigvalsh(gram)[0] if len(gram) else 0.0
    if ev_min <= 1e-14 * max(np.trace(gram), 1e-300):
        # singular as a whole: judge each column against the rest by its Schur complement
        for i, c in enumerate(cols):
            rest = np.setdiff1d(np.arange(jm.shape[1]), [c])
            a = js[:, rest]
            coef, *_ = np.linalg.lstsq(a, js[:, c], rcond=1e-12)
            free = float(np.sum((js[:, c] - a @ coef) ** 2))
            if free > 1e-24:
                out[i] = 1.96 / np.sqrt(free) / np.sqrt(n_eq)
        return out
    inv_diag = np.diag(np.linalg.inv(gram))[cols]
    # sqrt((J^T J)^-1_pp) in unscaled columns is sqrt(inv_diag) / scale_p, rms(J_p) = scale_p / sqrt(3N)
    return 1.96 * np.sqrt(np.maximum(inv_diag, 0.0)) / np.sqrt(n_eq)

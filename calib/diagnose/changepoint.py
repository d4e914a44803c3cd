"""station_shift: a tracker station moved once during the campaign, found by an exact change-point scan.

Every cut between two of a station's rows (in time) is scored with the robot held at the geometric fit:
the rigid fits of the predicted points to the measured ones before and after the cut, in closed form
from cumulative sums (Kabsch/Horn), so the scan over all cuts costs one pass. The station's rows after
the best cut are relabelled "<id>~shift" and fitted as a station of their own.
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.io.table import MeasurementTable

SHIFT = "station_shift"
SHIFT_SUFFIX = "~shift"
MIN_SEGMENT_ROWS = 6  # rows on each side of a change point: twice the three points that place a station


def relabel_shift(table: MeasurementTable, station: str, t_star: float) -> MeasurementTable:
    out = table.subset(np.arange(len(table)))
    out.station = [
        s + SHIFT_SUFFIX if (s == station and t > t_star) else s
        for s, t in zip(table.station, table.t_s.tolist(), strict=True)  # Python floats: the same values, faster
    ]
    return out


def rigid_prefix_rss(p: np.ndarray, x: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """RSS of the best rigid fit x ~ R p + t over the first c rows, for every c in counts (closed form
    from cumulative sums: sum|x - xm|^2 + sum|p - pm|^2 - 2 (s1 + s2 + d s3), Kabsch/Horn)."""
    p = p - p.mean(axis=0)
    x = x - x.mean(axis=0)
    idx = counts - 1
    c = counts[:, None].astype(float)
    sp, sx = np.cumsum(p, axis=0)[idx], np.cumsum(x, axis=0)[idx]
    spp = np.cumsum(np.sum(p**2, axis=1))[idx]
    sxx = np.cumsum(np.sum(x**2, axis=1))[idx]
    h = np.cumsum(np.einsum("ni,nj->nij", p, x), axis=0)[idx] - np.einsum("ni,nj->nij", sp, sx) / c[:, :, None]
    u, s, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("nji,nkj->nik", vt, u)))
    ss = spp - np.sum(sp**2, axis=1) / c[:, 0] + sxx - np.sum(sx**2, axis=1) / c[:, 0]
    return np.maximum(ss - 2.0 * (s[:, 0] + s[:, 1] + d * s[:, 2]), 0.0)


def shift_scan(base_points: np.ndarray, table: MeasurementTable, min_rows: int = MIN_SEGMENT_ROWS):
    """Exact change-point scan with the robot fixed: for each station and every cut between two of its
    rows (in time), the rigid fits before and after; the (station, t_star) that lowers the RSS most."""
    best = None
    stations = np.array(table.station)
    for sid in sorted(set(table.station)):
        rows = np.flatnonzero(stations == sid)
        rows = rows[np.argsort(table.t_s[rows], kind="stable")]
        m = len(rows)
        if m < 2 * min_rows:
            continue
        p, x, t = base_points[rows], table.xyz[rows], table.t_s[rows]
        cuts = np.arange(min_rows, m - min_rows + 1)
        cuts = cuts[t[cuts - 1] < t[cuts]]
        if len(cuts) == 0:
            continue
        split = rigid_prefix_rss(p, x, cuts) + rigid_prefix_rss(p[::-1], x[::-1], m - cuts)
        gain = rigid_prefix_rss(p, x, np.array([m]))[0] - split
        k = int(np.argmax(gain))
        if best is None or gain[k] > best[0]:
            best = (float(gain[k]), sid, float(t[cuts[k] - 1]))
    return None if best is None else best[1:]

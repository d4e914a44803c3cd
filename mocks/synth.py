"""Synthetic campaigns on the twin: the measurement table a campaign of given poses would record."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from trackcal.calib.io.table import MeasurementTable

if TYPE_CHECKING:
    from trackcal.mocks.twin import Twin


def simulate_campaign(
    twin: Twin,
    poses_deg: np.ndarray,
    repeat: int = 1,
    stations: list[str] | None = None,
    points: list[str] | None = None,
    noise_free: bool = False,
    seconds_per_measurement: float = 20.0,
) -> MeasurementTable:
    """Measure every pose (repeated `repeat` times) with every point from every station that sees it.

    Rows come in campaign order: station by station, point by point (the operator moves the reflector
    once per point), poses in plan order. Joint values are rounded to the controller's 0.0001 deg. The
    twin's robot state follows the motions (backlash), time advances per measurement (thermal drift).
    """
    stations = stations or sorted(twin.true_stations)
    points = points or sorted(twin.true_points)
    poses = np.round(np.asarray(poses_deg, dtype=float), 4)
    rows = []
    for s in stations:
        for pt in points:
            for k in range(repeat):
                for i, q in enumerate(poses):
                    if not twin.visible(q, pt, s):
                        continue
                    twin.move_to(q)
                    t = len(rows) * seconds_per_measurement
                    key = f"{s}/{pt}/pose{i}/rep{k}"
                    x = twin.exact(q, pt, s, t) if noise_free else twin.measure(q, pt, s, key, t)
                    rows.append((f"Q{i + 1}", s, pt, q, x, t))
    n = len(rows)
    return MeasurementTable(
        seq=np.arange(1, n + 1),
        t_s=np.array([r[5] for r in rows], dtype=float),
        pose=[r[0] for r in rows],
        station=[r[1] for r in rows],
        point=[r[2] for r in rows],
        q_deg=np.array([r[3] for r in rows]).reshape(n, poses.shape[1]),
        xyz=np.array([r[4] for r in rows]).reshape(n, 3),
        source="twin",
    )

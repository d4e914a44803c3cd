"""ISO 9283 pose accuracy of the real UR10 on Series D, with the nominal model and with the model calibrated on B.

Data: christianlandgraf/ipa-robot-accuracy (MIT), Landgraf et al., "A Hybrid Neural Network Approach for
Increasing the Absolute Accuracy of Industrial Robots", IEEE CASE 2021, pp. 468-474.

Series D holds 632 poses on ISO 9283-style cubes, each commanded once, measured four months after B with the
tracker set up elsewhere. For each model (nominal: the datasheet geometry with the T-Mac's nominal offset;
geometric: identified on B, `studies.ur10_ipa.study`'s fit; diagnose's: the geometric model extended by the causes
`trackcal diagnose` names on B) the station of D is located on LOCATE poses of D drawn at random (robot and tool
point held), and the other poses are held out. On them, the pose accuracy of ISO 9283:1998, 7.2 with one cycle
per pose: AP_P = |x - c|, x the attained T-Mac centre (measured, in the base frame of the located station), c where
the model puts it at the commanded joints: what the robot would attain if its targets were compensated with that
model (compensation makes the model reach the commanded pose; the robot then misses it by
the model's error). The standard's repeatability needs repeated cycles: D has none, so RP is not computed.

`python -m studies.ur10_ipa.iso9283_d [--data DIR] [--out docs/ur10-iso9283.md]` (about a minute: diagnose on B).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from trackcal.calib.diagnose import diagnose
from trackcal.calib.diagnose.extensions import rebuild
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Identification, identify, model_points
from trackcal.calib.iso9283 import pose_accuracy
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model.subset import identifiable_subset
from trackcal.campaign.importers.ipa_ur10 import POINT, read_ipa_series

from .error_map_check import STATION_ONLY
from .study import CITATION, DATA, SERIES

LOCATE = 10  # poses of D that locate its station; the rest are held out
SEED = 9283


def held_out_accuracy(chain, fit: Identification, d, locate: np.ndarray, held: np.ndarray) -> dict:
    """AP_P (one cycle per pose) of `fit`'s model on D's held-out poses, D's station located on `locate`."""
    first, rows = d.subset(locate), d.subset(held)
    ext = None if fit.extension is None else rebuild(fit.extension, chain, first)
    loc = identify(chain, first, fit.points, fit.params, dev0=fit.dev, extension=ext, ext0=fit.ext, fixed=STATION_ONLY)
    (station,) = loc.stations.values()
    attained = (rows.xyz - station.translation) @ station.rotation  # R^T (x - t)
    cov = np.einsum("ji,njk,kl->nil", station.rotation, TrackerNoise().covariance(rows.xyz), station.rotation)
    ext = None if fit.extension is None else rebuild(fit.extension, chain, rows)
    commanded = model_points(
        Kinematics(chain, fit.params), np.radians(rows.q_deg), fit.points[POINT], fit.dev, ext, fit.ext
    )
    figs = [pose_accuracy(attained[i : i + 1], commanded[i], cov[i : i + 1]) for i in range(len(rows))]
    ap = np.array([f.value for f, _ in figs])
    u95 = np.array([f.u95 for f, _ in figs])
    offset = np.array([o for _, o in figs])
    return {
        "n": len(ap),
        "mean": ap.mean(),
        "median": float(np.median(ap)),
        "p95": float(np.percentile(ap, 95)),
        "max": ap.max(),
        "u95_median": float(np.median(u95)),
        "mean_offset": offset.mean(axis=0),
        "rms3": float(np.sqrt(np.mean(ap**2))),
    }


def run(data: Path = DATA, locate: int = LOCATE, seed: int = SEED) -> dict:
    cell = load_cell("ur10-ipa")
    chain = cell.chain
    tmac = {POINT: cell.tool_points[POINT]}
    b = read_ipa_series(data / SERIES["B"], station="B")
    d = read_ipa_series(data / SERIES["D"], station="D")
    irr, _ = irreducible_params(chain)
    params, _ = identifiable_subset(chain, irr, np.radians(b.q_deg), tmac)
    chosen = diagnose(chain, b, tmac, params, None)
    causes = " + ".join(c["cause"] for c in chosen.causes) or "geometric"
    models = {
        "nominal": identify(chain, b, tmac, [], fixed=STATION_ONLY),
        "geometric, calibrated on B": chosen.geometric,
        f"diagnose's model on B ({causes})": chosen.extended or chosen.geometric,
    }
    order = np.random.default_rng(seed).permutation(len(d))
    loc, held = np.sort(order[:locate]), np.sort(order[locate:])
    return {name: held_out_accuracy(chain, fit, d, loc, held) for name, fit in models.items()}


def report(results: dict, locate: int, seed: int) -> str:
    lines = [
        "# ISO 9283 pose accuracy of a real UR10 (Series D), before and after calibration",
        "",
        f"Data: {CITATION}; christianlandgraf/ipa-robot-accuracy (MIT).",
        "Made by `python -m studies.ur10_ipa.iso9283_d`.",
        "",
        f"D's station located on {locate} of its 632 poses (drawn with seed {seed}); the figures are over the other "
        "poses, none of which the models saw. AP_P is ISO 9283:1998, 7.2 with one cycle per pose (D commands each "
        "pose once; the standard's 30 cycles and its repeatability RP need repeats, which D does not hold): the "
        "distance between the attained T-Mac centre and where the model puts it at the commanded joints. The nominal "
        "figures are measured (the robot as it stood); the calibrated models' figures are **predicted**: each model's "
        "residuals on poses it never saw, what the robot would attain with targets compensated by that model if the "
        "model holds. No compensated UR10 was measured again (the data set holds none). U is the AT901 model's "
        "expanded uncertainty (k = 2) of one AP_P.",
        "",
        "| model | poses | AP_P mean (mm) | median | 95th percentile | max | RMS | mean offset x, y, z (mm) "
        "| U median (mm) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, r in results.items():
        off = ", ".join(f"{v:+.3f}" for v in r["mean_offset"])
        lines.append(
            f"| {name} | {r['n']} | {r['mean']:.3f} | {r['median']:.3f} | {r['p95']:.3f} | {r['max']:.3f} "
            f"| {r['rms3']:.3f} | {off} | {r['u95_median']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--out", type=Path, default=Path("docs/ur10-iso9283.md"))
    args = ap.parse_args(argv)
    results = run(args.data)
    text = report(results, LOCATE, SEED)
    args.out.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

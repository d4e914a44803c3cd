"""Three physical candidates (issue 36, calib/diagnose/point_effects.py): a station's range scale (its air data), a
nest's sag along gravity, the wrist's coupling ratios. Each is recovered on the twin within its 95 % interval and
named; the point features' Jacobian is the finite differences'; a fit beyond a physical range is refused;
compensation corrects the coupling and leaves the measurement's matters geometric.

The twin's effects are scaled so that what a geometric calibration cannot absorb is 2x to 5x the AT901's noise
(15 um per coordinate at 2-4 m: sqrt((5^2 + 2 * 16^2) / 3) um, calib/identify/noise.py), as tests/test_diagnose.py
draws them.
"""

import numpy as np
import pytest

from trackcal.calib.compensate import GEOMETRIC_ONLY, joint_error_function
from trackcal.calib.diagnose import diagnose
from trackcal.calib.diagnose.extensions import build_extension
from trackcal.calib.diagnose.plausibility import COUPLING_MAX, NEST_SAG_MAX_MM, RANGE_SCALE_MAX, implausible
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Problem
from trackcal.calib.model.extension import combine
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model_file import model_from_doc, predict_table
from trackcal.campaign.jobs.identify import model_doc
from trackcal.mocks.twin import Twin, simulate_campaign

NOISE_RMS_MM = 0.015  # AT901 model at 2-4 m (module docstring)


def twin_campaign(cell, cause: str, seed: int, n_poses: int = 40):
    rng = np.random.default_rng(seed)
    twin = Twin(cell, seed=seed, effects={cause: rng.uniform(2.0, 5.0) * NOISE_RMS_MM})
    return twin, simulate_campaign(twin, np.degrees(random_poses(cell, n_poses, rng)))


def truth(twin: Twin, cause: str, table) -> dict[str, float]:
    """The twin's true parameters as the candidate names them (internal units: a fraction, mm), relative to the
    candidate's reference (the first station, the first point of the table) where it has one."""
    h = twin.hidden
    if cause == "range_scale":
        first, ref = table.station[0], h.range_scale.get(table.station[0], 0.0)
        return {f"k_{s}": h.range_scale.get(s, 0.0) - ref for s in dict.fromkeys(table.station) if s != first}
    if cause == "nest_sag":
        first, ref = table.point[0], h.nest_sag.get(table.point[0], 0.0)
        return {f"c_{p}": h.nest_sag.get(p, 0.0) - ref for p in dict.fromkeys(table.point) if p != first}
    n = len(h.coupling)
    return {f"c{i + 1}{j + 1}": h.coupling[i, j] for i, j in ((n - 2, n - 3), (n - 1, n - 3), (n - 1, n - 2))}


@pytest.mark.parametrize("cause", ["range_scale", "nest_sag", "wrist_coupling"])
def test_candidate_is_named_and_recovered_on_the_twin(kr270, cause):
    cell = kr270
    twin, table = twin_campaign(cell, cause, 20001)
    params = irreducible_params(cell.chain)[0]
    d = diagnose(cell.chain, table, cell.tool_points, params, TrackerNoise(), seed=20001)
    assert d.cause == cause and [c["cause"] for c in d.causes] == [cause], (d.cause, d.causes, d.refused)
    assert d.holdout_extended_mm < d.holdout_geometric_mm
    res = d.extended
    got = dict(zip(res.extension.names, res.ext, strict=True))
    half = dict(zip(res.extension.names, res.ext_ci95(), strict=True))
    want = truth(twin, cause, table)
    assert set(got) == set(want)
    for name, value in want.items():
        assert abs(got[name] - value) <= half[name], (name, got[name], value, half[name])
        assert abs(value) > 2 * half[name]  # recovered, not merely consistent with zero
    # model.json carries it: predict reproduces the measurements to the extended fit's residual level (a
    # geometric model leaves the effect's 2x-5x the noise)
    model = model_from_doc(model_doc(cell, d.table, res, d.geometric, d.shift, "twin"))
    pred = predict_table(model, table)
    rms = float(np.sqrt(np.mean((pred.xyz - table.xyz) ** 2)))
    assert rms <= 1.01 * float(np.sqrt(np.mean(res.residuals**2)))


def test_point_features_jacobian_matches_finite_differences(kr270):
    cell = kr270
    chain = cell.chain
    twin, table = twin_campaign(cell, "range_scale", 7, n_poses=8)
    ext = combine(
        [build_extension(c, chain, table) for c in ("range_scale", "nest_sag", "wrist_coupling")]
        + [build_extension("thermal_drift", chain, table, names=["e_base"])],
        cause="nest_sag",
    )
    assert ext.displacement is not None and ext.range_scale is not None and ext.growth is not None
    params = irreducible_params(chain)[0]
    rng = np.random.default_rng(3)
    # 50 ppm of range scale, 0.1 mm of sag, 0.1 % of coupling, 10 ppm/h of growth (physical sizes, plausibility.py)
    theta = np.concatenate([[5e-5], [0.1, -0.05], [1e-3, -1e-3, 5e-4], [10e-6 / 3600.0]])
    assert len(theta) == ext.size
    for noise in (None, TrackerNoise()):  # unwhitened and whitened rows
        problem = Problem(
            chain,
            table,
            cell.tool_points,
            params,
            noise,
            extension=ext,
            ext0=theta,
            dev0=rng.normal(0.0, 1e-3, len(params)),
        )
        state = problem.initial
        _, jm = problem.residual_and_jacobian(state)
        k = len(params)
        for c in [0, *range(k, k + ext.size), k + ext.size, k + ext.size + 4, problem.n_cols - 1]:
            step = np.zeros(problem.n_cols)
            h = 1e-4 / np.sqrt(np.mean(jm[:, c] ** 2))  # moves the prediction by ~0.1 um
            step[c] = h
            rp = problem.residual(problem.retract(state, step))
            rm = problem.residual(problem.retract(state, -step))
            np.testing.assert_allclose(-(rp - rm) / (2 * h), jm[:, c], rtol=1e-5, atol=1e-6 * np.abs(jm[:, c]).max())


def test_fits_beyond_the_physical_ranges_are_refused(kr270):
    cell = kr270
    _, table = twin_campaign(cell, "range_scale", 7, n_poses=8)
    ext = combine([build_extension(c, cell.chain, table) for c in ("range_scale", "nest_sag", "wrist_coupling")])
    inside = np.array(
        [
            0.9 * RANGE_SCALE_MAX,
            0.9 * NEST_SAG_MAX_MM,
            -0.9 * NEST_SAG_MAX_MM,
            0.9 * COUPLING_MAX,
            0.0,
            -0.9 * COUPLING_MAX,
        ]
    )
    assert implausible(ext, inside) == []
    # 300 ppm is 1100 hPa of air pressure wrong; 2 mm of sag a loose nest; 2 % of coupling a wrong gear train
    outside = np.array([300e-6, 2.0, 0.0, 0.02, 0.0, 0.0])
    named = implausible(ext, outside)
    assert len(named) == 3
    assert named[0].startswith("range_scale k_") and named[1].startswith("nest_sag c_")
    assert named[2].startswith("wrist_coupling c54")


def _model(cell, twin, table, cause: str):
    params = irreducible_params(cell.chain)[0]
    d = diagnose(cell.chain, table, cell.tool_points, params, TrackerNoise(), seed=20001, causes=(cause,))
    assert d.cause == cause
    return model_from_doc(model_doc(cell, d.table, d.extended, d.geometric, d.shift, "twin"))


def test_compensation_corrects_the_coupling_and_leaves_the_measurement_geometric(kr270):
    cell = kr270
    twin, table = twin_campaign(cell, "wrist_coupling", 20001)
    model = _model(cell, twin, table, "wrist_coupling")
    offsets, ignored, notes = joint_error_function(model)
    assert offsets is not None and not ignored
    names, theta = model.extension_values()
    c = dict(zip(names, theta, strict=True))
    q = np.radians(np.array([[10.0, -60.0, 30.0, 40.0, -50.0, 70.0]]))
    dq = offsets(q)[0]
    # dq5 = c54 q4, dq6 = c64 q4 + c65 q5 (the form of the candidate), the other joints untouched
    np.testing.assert_allclose(
        dq, [0, 0, 0, 0, c["c54"] * q[0, 3], c["c64"] * q[0, 3] + c["c65"] * q[0, 4]], atol=1e-15
    )
    for cause in ("range_scale", "nest_sag"):
        twin, table = twin_campaign(cell, cause, 20001)
        offsets, ignored, notes = joint_error_function(_model(cell, twin, table, cause))
        assert offsets is None and not ignored and notes == [GEOMETRIC_ONLY[cause]]

"""Any serial chain: joint axes in any direction (tilted, skew, near-parallel), the generated parameter set complete
and irreducible (hypothesis over random chains), known deviations recovered by the solver, and a joint that never
moves reported as not identifiable."""

import dataclasses
import json
import subprocess

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from tests.helpers import TRACKCAL
from trackcal.calib.identify.solver import identify
from trackcal.calib.io.table import MeasurementTable, write_table
from trackcal.calib.model.chain import Chain, ChainError, chain_from_dict
from trackcal.calib.model.identifiability import identification_jacobian, numerical_rank, random_configuration
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model.rigid import exp_so3
from trackcal.campaign.jobs.diagnose import DiagnoseOptions, run_diagnose

TOOL = np.array([[277.0, -47, -94], [276, -48, 94], [278, 104, -2]])
RTOL = 1e-6  # central differences with h = 1e-6 are good to ~1e-9 of a column; real singular values are far above


@st.composite
def chains(draw) -> Chain:
    """3-6 revolute joints; each link aligned (multiples of 90 deg), tilted anywhere, or tilted by 0.5-5 deg from
    an aligned one (near-parallel / near-perpendicular: Hayati's case); link offsets often zero (intersecting axes)."""
    n = draw(st.integers(3, 6))
    joints = []
    for _ in range(n):
        link = [
            draw(st.sampled_from([0, 0, 1])) * draw(st.integers(-600, 600).filter(lambda v: abs(v) >= 50))
            for _ in range(3)
        ]
        kind = draw(st.sampled_from(["aligned", "tilted", "near"]))
        rpy = [90.0 * draw(st.integers(-1, 2)) for _ in range(3)]
        if kind == "tilted":
            rpy = [draw(st.floats(-180, 180)) for _ in range(3)]
        elif kind == "near":
            rpy[draw(st.integers(0, 2))] += draw(st.floats(0.5, 5.0)) * draw(st.sampled_from([1, -1]))
        axis = draw(st.sampled_from(["x", "y", "z", "-x", "-y", "-z"]))
        joints.append({"axis": axis, "link_mm": link, "link_rpy_deg": rpy})
    return chain_from_dict({"name": "random", "joints": joints})


def _params_or_skip(chain):
    try:
        return irreducible_params(chain)
    except ChainError as exc:  # two parallel axes on one line: refused, rightly (test_params)
        assume("coincide" not in str(exc))
        raise


def full_deviation_jacobian(chain: Chain, q: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central differences of the points w.r.t. all 6 deviations of every link (translation then rotation, in the
    frame after the joint's rotation), stacked as identification_jacobian stacks its rows (point by point)."""
    cols = []
    for j in range(chain.dof):
        for i in range(6):
            pts = []
            for s in (1.0, -1.0):
                e = np.zeros(6)
                e[i] = s * h
                jt = chain.joints[j]
                moved = dataclasses.replace(
                    jt, translation=jt.translation + e[:3], rotation=exp_so3(e[3:]) @ jt.rotation
                )
                other = Chain(chain.name, chain.base, chain.joints[:j] + (moved,) + chain.joints[j + 1 :])
                r, o = Kinematics(other, []).end_frames(q)
                pts.append((o[None] + np.einsum("mij,pj->pmi", r, TOOL)).ravel())
            cols.append((pts[0] - pts[1]) / (2 * h))
    return np.array(cols).T


def check_complete_and_irreducible(chain, seed):
    kept, _ = _params_or_skip(chain)
    q = random_configuration(chain, 20, np.random.default_rng(seed))
    j = identification_jacobian(chain, kept, q, TOOL)
    rank = numerical_rank(j, RTOL)
    # irreducible: every parameter column adds to the rank of the station and tool-point columns (which alone lose
    # one when every axis is parallel: the tool points and the station then slide together along the axes)
    others = identification_jacobian(chain, [], q, TOOL)
    assert rank == numerical_rank(others, RTOL) + len(kept)
    assert np.all(np.linalg.norm(j, axis=0) > 0)
    # complete: the station and tool-point columns plus ALL per-link deviations span no more than the kept set does
    everything = np.hstack([full_deviation_jacobian(chain, q), others])
    assert numerical_rank(everything, RTOL) == rank
    # counting (Everett, Driels, Mooring: 4R + 2P + 6 for the whole chain with base and tool) less the 6 of the
    # free station and the 6 of the free tool points; one more when every axis is parallel (the planar arm)
    axes = Kinematics(chain, []).jacobian(np.zeros((1, chain.dof)), TOOL[0]).joint_axes[0]
    planar = np.allclose(np.abs(axes.T @ axes[:, -1]), 1.0, atol=1e-9)
    assert len(kept) == 4 * chain.dof - 6 + planar


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(chain=chains(), seed=st.integers(0, 2**31))
def test_generated_set_is_complete_and_irreducible(chain, seed):
    check_complete_and_irreducible(chain, seed)


@pytest.mark.slow
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(chain=chains(), seed=st.integers(0, 2**31))
def test_generated_set_is_complete_and_irreducible_many_chains(chain, seed):
    check_complete_and_irreducible(chain, seed)


def _table(chain, dev, params, q, station_r, station_t, points, noise_mm, rng) -> MeasurementTable:
    kin = Kinematics(chain, params)
    rows_q, pose, point, xyz = [], [], [], []
    for pid, pt in points.items():
        p = kin.points(q, pt, dev) @ station_r.T + station_t
        xyz.append(p + rng.normal(0.0, noise_mm, p.shape))
        rows_q.append(q)
        pose += [f"P{i}" for i in range(len(q))]
        point += [pid] * len(q)
    n = len(pose)
    return MeasurementTable(
        seq=np.arange(n),
        t_s=np.zeros(n),
        pose=pose,
        station=["S1"] * n,
        point=point,
        q_deg=np.degrees(np.vstack(rows_q)),
        xyz=np.vstack(xyz),
        source="synthetic",
    )


def _recover(chain, seed, noise_mm):
    kept, _ = irreducible_params(chain)
    rng = np.random.default_rng(seed)
    truth = np.array([rng.normal(0, 0.5) if p.is_length else rng.normal(0, 1e-3) for p in kept])
    nominal = {f"T{i}": pt for i, pt in enumerate(TOOL)}
    true_points = {k: v + rng.normal(0, 0.5, 3) for k, v in nominal.items()}
    q = random_configuration(chain, 40, rng)
    table = _table(
        chain, truth, kept, q, exp_so3([0.01, -0.02, 0.5]), np.array([2500.0, 300, -400]), true_points, noise_mm, rng
    )
    return kept, truth, identify(chain, table, nominal, kept)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(chain=chains(), seed=st.integers(0, 2**31))
def test_known_deviations_are_recovered_noise_free(chain, seed):
    _params_or_skip(chain)
    kept, truth, res = _recover(chain, seed, 0.0)
    scale = np.array([1.0 if p.is_length else 1000.0 for p in kept])  # angles at a 1 m lever, mm
    assert np.max(np.abs((res.dev - truth) * scale)) < 1e-6


def test_known_deviations_are_recovered_from_a_noisy_table_within_their_intervals():
    # a Yaskawa-like torso (issue 23): shoulder tilted 15 deg, then an offset elbow and a spherical wrist
    doc = {
        "joints": [
            {"axis": "z", "link_mm": [150, 0, 300], "link_rpy_deg": [15, 0, 0]},
            {"axis": "z", "link_mm": [100, 0, 200], "link_rpy_deg": [90, 0, 0]},
            {"axis": "z", "link_mm": [600, 0, 0]},
            {"axis": "z", "link_mm": [100, 0, 0], "link_rpy_deg": [90, 0, 0]},
            {"axis": "z", "link_mm": [0, 0, 550], "link_rpy_deg": [-90, 0, 0]},
            {"axis": "z", "link_mm": [0, 0, 0], "link_rpy_deg": [90, 0, 0]},
            {"axis": "z", "link_mm": [0, 0, 100]},
        ]
    }
    chain = chain_from_dict(doc)
    kept, truth, res = _recover(chain, 7, 0.01)
    assert len(kept) == 4 * 7 - 6
    z = (res.dev - truth) / (res.param_ci95() / 1.96)
    assert np.max(np.abs(z)) < 4.5  # 22 parameters, each |z| > 4.5 has probability 7e-6


def test_a_joint_that_never_moves_is_reported_not_refused(kr270, tmp_path):
    """KR-270 table with A4 held at 30 deg: dq4 and the parameters its two links then share are named in one warning
    line and left at nominal; the rest is identified (no singular fit, no refusal) down to the table's rounding."""
    kept, table = _still_table(kr270, tmp_path / "still.csv")
    run = subprocess.run(
        [
            *TRACKCAL,
            "identify",
            table.source,
            "--cell",
            "kr270",
            "--weighting",
            "iid",
            "--out",
            str(tmp_path / "m.json"),
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr
    doc = json.loads((tmp_path / "m.json").read_text())
    lines = run.stderr.strip().splitlines()
    # one line; with A4 still the kept parameters also absorb the still links' deviations (the model holds at
    # A4 = 30 deg only) and leave the physical bounds of calib.model.plausible, so that line first says the model
    # is unusable for compensation
    assert len(lines) == 1 and "UNUSABLE" in lines[0] and "; and joint A4 never moves in" in lines[0], lines
    assert doc["not_identifiable"] in lines[0]
    dropped = doc["not_identifiable"].split(": ")[1].split(" not identifiable")[0].split()
    # joint 4 still: links 3 and 4 become one rigid body between axes 3 and 5, and the robot counts as a 5R one:
    # 4 x 5 - 6 = 14 parameters of the 18 stay (the counting of calib.model.params), the 4 others from those links
    assert len(dropped) == 4 and set(dropped) <= {"dq4", "py4", "pz4", "phiz4", "px3", "pz3", "phiz3"}
    assert set(doc["parameters"]) == {p.name for p in kept} - set(dropped)
    # noise-free, but the table keeps the controller's 4 decimals of a degree: 0.5e-4 deg at a 3 m lever is 2.6 µm
    assert doc["residuals"]["after"]["coord_max_mm"] < 0.01 and doc["converged"]


def _still_table(kr270, path):
    chain = kr270.chain
    kept, _ = irreducible_params(chain)
    rng = np.random.default_rng(3)
    q = random_configuration(chain, 40, rng) * 0.5
    q[:, 3] = np.radians(30.0)
    truth = np.array([rng.normal(0, 0.3) if p.is_length else rng.normal(0, 5e-4) for p in kept])
    table = _table(
        chain, truth, kept, q, exp_so3([0.0, 0.0, 0.3]), np.array([3000.0, 0, 0]), kr270.tool_points, 0.0, rng
    )
    table.source = str(path)
    write_table(table, table.source)
    return kept, table


@pytest.mark.slow
def test_diagnose_goes_on_past_a_joint_that_never_moves(kr270, tmp_path):
    """Before: "unidentifiable set-up". About 30 s on the loaded machine (every cause is fitted)."""
    _, table = _still_table(kr270, tmp_path / "still.csv")
    done = run_diagnose(
        DiagnoseOptions(data=table.source, cell="kr270", json=str(tmp_path / "v.json"), folds=2, weighting="iid")
    )
    assert done.still is not None and done.still.startswith("joint A4 never moves in")


@pytest.mark.parametrize("tilt_rad", [1.7e-12, 1e-7])
def test_intersecting_axes_tilted_below_the_trackers_precision_coincide(tilt_rad):
    # hypothesis found joints 1 and 2 on the x axis through the origin, joint 1's link turned by 1.7e-12 rad about z
    # (with the rest of its chain, the rotation's pivot came out just above the old absolute 1e-9 mm): the
    # elimination took that tilt for real and kept a set whose Jacobian lacks one rank at RTOL. So it did for any
    # tilt up to 1e-6 rad (1e-7 here). A tilt that moves the far end by less than 1e-6 of the reach is none.
    joints = [
        {"axis": "x", "link_mm": [0, 0, 0], "link_rpy_deg": [0, 0, float(np.degrees(tilt_rad))]},
        {"axis": "x", "link_mm": [0, 0, 0], "link_rpy_deg": [0, 0, 1]},
        {"axis": "x", "link_mm": [0, 0, 224]},
        {"axis": "x", "link_mm": [0, 0, 349]},
    ]
    with pytest.raises(ChainError, match="coincide"):
        irreducible_params(chain_from_dict({"name": "random", "joints": joints}))


@pytest.mark.parametrize("tilt_rad", [1e-9, 1e-7, 1e-3])
def test_parallel_axes_keep_one_complete_irreducible_set_whatever_their_tilt(tilt_rad):
    # Hayati's case: offset parallel axes keep both rotations, tilted by nothing, by less than the tracker resolves
    # or by 0.06 deg: the same set, complete and irreducible
    def chain(tilt):
        return chain_from_dict(
            {
                "name": "random",
                "joints": [
                    {"axis": "z", "link_mm": [0, 0, 0]},
                    {"axis": "y", "link_mm": [400, 0, 0], "link_rpy_deg": [tilt, 0, 0]},
                    {"axis": "y", "link_mm": [300, 0, 0]},
                    {"axis": "y", "link_mm": [0, 0, 100]},
                    {"axis": "z"},
                ],
            }
        )

    tilted = chain(float(np.degrees(tilt_rad)))
    assert irreducible_params(tilted)[0] == irreducible_params(chain(0.0))[0]
    check_complete_and_irreducible(tilted, 0)

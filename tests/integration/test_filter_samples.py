"""The sample programs of configs/programs filtered end to end on their robots' twins, checked against the twin's TRUE
robot (issue 38): KRL (KR C2 and KR C4 syntax) on the KR-270, RAPID on the IRB 120, the cell script on the UR10.

Each sample is read by its family's reader (drivers.families.program_readers: the reader `trackcal filter` picks),
filtered with a model identified from a simulated campaign on the twin, and every target an absolute move uses is
checked: the filtered target, through the NOMINAL kinematics (q_cal is what the nominal controller makes of it, checked
in tests/calib/test_program_filter.py against an independent FK), puts the true robot's TCP within the stated 95 %
bound of the intended pose; the target as written does not (the twins' errors are ~1 mm: Table 8 of the paper for
the KR-270, N(0, 0.3 mm) per length for the others, mocks.twin)."""

from pathlib import Path

import numpy as np
import pytest

from tests.calib.test_program_filter import identified, true_flange
from trackcal.calib.program_filter import filter_targets
from trackcal.campaign.jobs.filter_program import RELATIVE, reference_joints
from trackcal.drivers.families import program_readers

PROGRAMS = Path(__file__).resolve().parents[2] / "configs" / "programs"
SAMPLES = [
    ("kr270", "krc2", "PALLET.src"),
    ("kr270", "krc4", "DEBURR.src"),
    ("irb120", "abb", "CellDemo.mod"),
    ("ur10", "ur", "cell_demo.script"),
]


@pytest.mark.parametrize(("cell", "folder", "main"), SAMPLES)
def test_a_sample_program_filtered_puts_the_true_robot_within_its_bound(cell, folder, main):
    files = {p.name: p.read_bytes().decode("latin-1") for p in sorted((PROGRAMS / folder).iterdir())}
    read = program_readers()[Path(main).suffix](files)
    _, twin, model = identified(cell, 3)
    res = filter_targets(model, read.targets, reference_joints(model))
    absolute = [i for i, t in enumerate(read.targets) if t.motion and not RELATIVE.search(t.motion) and not t.joint]
    assert len(absolute) >= 4, [t.name for t in read.targets]  # each sample moves to several Cartesian targets
    # every absolute Cartesian target of a sample is meant to be filtered (the samples avoid singular poses)
    assert all(not res.why[i] for i in absolute), {read.targets[i].name: res.why[i] for i in absolute}
    miss, miss0, bound = [], [], []
    for i in absolute:
        t = read.targets[i]
        intended = (t.base @ t.value)[:3, 3]
        for q_deg, out in ((res.q_calibrated_deg[i], miss), (res.q_nominal_deg[i], miss0)):
            out.append(np.linalg.norm((true_flange(twin, np.radians(q_deg)) @ t.tool)[:3, 3] - intended))
        bound.append(res.bound95_mm[i])
    miss, miss0, bound = map(np.array, (miss, miss0, bound))
    # one model's targets lie close together and share its error: they are one trial of the 95 % claim, not several
    # (the claim's rate is tested over 3 and, slow, 30 campaigns in tests/calib/test_program_filter.py). Here: the
    # reader's frames and configuration carried through, so no target misses by more than twice its bound (a frame or
    # a unit wrong gives misses of the twin's ~1 mm errors, or of the tool's length)
    assert np.all(miss <= 2.0 * bound), (miss, bound)
    assert np.all(miss0 > bound), (miss0, bound)

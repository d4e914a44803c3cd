"""A station shift between two reflector blocks (calib.diagnose.confounds): a move only beyond a displacement of the
reflectors measured after it.

Two campaigns whose change point falls between reflector blocks, so that no reflector is measured at the station on
both sides of it: the twin's (mocks/twin.py) station S1 moved during its block (seed 30003 of test_diagnose.py's many
seeds: refused as a reflector displacement before, the verdict unexplained), and the independent twin's nest sagging
along gravity (tests/independent_twin.py, seed 36002: a shift of station S2 absorbed the sag and made poses measured
after the campaign 11 % worse, test_diagnose_floor.py). The level is the first step's, ALPHA over the causes judged.
"""

from tests.calib.diagnose.test_diagnose import hidden_campaign
from tests.independent_twin import campaign
from trackcal.calib.diagnose.changepoint import SHIFT
from trackcal.calib.diagnose.confounds import shift_between_blocks, unrevisited
from trackcal.calib.diagnose.extensions import CAUSES
from trackcal.calib.diagnose.fits import context, n_extra, whole_fit
from trackcal.calib.diagnose.selection import ALPHA
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify
from trackcal.calib.model.params import irreducible_params

LEVEL = ALPHA / len(CAUSES)


def refusal(cell, table, params) -> tuple[list[str], list[str]]:
    """(the reflectors measured after the change point when none is on both sides of it, shift_between_blocks' answer)
    for the geometric model + station_shift, as `calib.diagnose.judge` judges it at the first step."""
    geo = identify(cell.chain, table, cell.tool_points, params, noise=TrackerNoise())
    ctx = context(cell.chain, table, params, TrackerNoise(), geo, (SHIFT,))
    fit = whole_fit(ctx, (SHIFT,))
    return unrevisited(table, fit.shift), shift_between_blocks(ctx, (), fit, geo.dof - n_extra(ctx, (SHIFT,)), LEVEL)


def test_a_station_moved_between_reflector_blocks_is_a_move(kr270):
    # beyond P3's displacement in the flange frame and along gravity: F test p ~ 1e-220
    table, _ = hidden_campaign(kr270, 30003, "station_shift")
    after, refused = refusal(kr270, table, irreducible_params(kr270.chain)[0])
    assert after == ["P3"] and refused == []


def test_a_nest_sag_taken_for_a_station_shift_is_refused(kr270):
    # beyond P2's and P3's displacements the shift of S2 leaves what noise would (F test p = 0.81)
    c = campaign(kr270, "sagging_nest", 36002, 20)
    after, refused = refusal(kr270, c.table, c.params)
    assert after == ["P2", "P3"]
    assert len(refused) == 1 and "station S2" in refused[0] and "displacement of the reflectors" in refused[0]

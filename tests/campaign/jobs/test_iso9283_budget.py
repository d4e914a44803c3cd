"""What the ISO 9283 budget reads from a session and its model (campaign.jobs.iso9283_budget): the tool file's
reflector centring, the meteo record's half-range, the model's 95 % intervals (a hand-made model states none)."""

import numpy as np
import pytest

from trackcal.calib.model_file import Model
from trackcal.calib.uncertainty_budget import CI95_TO_SIGMA
from trackcal.campaign.errors import InputError
from trackcal.campaign.jobs.iso9283_budget import BudgetContext, centring_mm, temperature_halfrange


def test_reflector_centring_from_the_tool_file():
    """`reflector: {centring_um: 5}` is 0.005 mm; none stated is None (the budget says so); a mistake is one line."""
    assert centring_mm({"name": "t", "reflector": {"centring_um": 5}}) == pytest.approx(0.005)
    assert centring_mm({"name": "t"}) is None and centring_mm(None) is None
    for bad in (-1, "5 um", True, float("nan")):
        with pytest.raises(InputError, match="reflector.centring_um") as exc:
            centring_mm({"reflector": {"centring_um": bad}})
        assert "\n" not in str(exc.value)


def test_temperature_halfrange_of_the_record():
    """19.7 to 19.9 degC recorded: +-0.1 K about the middle; nothing recorded: None."""
    assert temperature_halfrange(["19.70", "19.90", "19.80"]) == pytest.approx(0.1)
    assert temperature_halfrange([]) is None and temperature_halfrange(None) is None


def test_model_intervals_become_standard_uncertainties():
    """model.json's 95 % half-widths / 1.96 (the station's rotation from degrees to radians); a model without them
    (written by hand) contributes nothing from the calibration."""
    doc = {
        "stations": {"S1": {"ci95_translation_mm": [0.0196, 0.0392, 0.0588], "ci95_rotation_deg": [0.001, 0, 0]}},
        "tool_points": {"P1": {"ci95_mm": [0.00196, 0, 0]}},
    }
    st = type("S", (), {"rotation": np.eye(3), "translation": np.zeros(3)})()
    model = Model(None, [], np.zeros(0), {"S1": st}, {"P1": np.zeros(3)}, doc)  # type: ignore[arg-type]
    s = BudgetContext(model, "S1", "P1", np.array([np.eye(3)]), "t", None, None).setting(0, np.ones((2, 3)))
    assert s.station_u[:3] == pytest.approx([0.01, 0.02, 0.03])
    assert s.station_u[3] == pytest.approx(np.radians(0.001) * CI95_TO_SIGMA)
    assert s.point_u == pytest.approx([0.001, 0.0, 0.0])
    bare = Model(None, [], np.zeros(0), {"S1": st}, {"P1": np.zeros(3)}, {})  # type: ignore[arg-type]
    s = BudgetContext(bare, "S1", "P1", np.array([np.eye(3)]), "t", None, None).setting(0, np.ones((2, 3)))
    assert not s.station_u.any() and not s.point_u.any()

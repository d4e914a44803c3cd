"""The hardware config's traceability keys of the tracker (#39): serial, certificate, certificate_date, certificate_due
are checked when the config is read: one line naming the file and the key."""

from pathlib import Path

import pytest
import yaml

from trackcal.campaign.cells.hardware import load_hardware
from trackcal.campaign.errors import InputError

EXAMPLE = Path(__file__).parents[3] / "configs" / "hardware" / "example-cell.yaml"


def test_example_cell_states_its_tracker_certificate():
    t = load_hardware(EXAMPLE).tracker
    assert t["serial"] and t["certificate"] and t["certificate_date"] < t["certificate_due"]


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("certificate_date", "31.12.2018", "expected a date YYYY-MM-DD"),
        ("certificate_due", "2017-01-01", "is before its certificate_date"),
        ("serial", "", "expected a non-empty text"),
    ],
)
def test_hardware_config_checks_the_certificate_keys(tmp_path, key, value, message):
    """A mistake in the traceability keys is one line naming the file and the key (exit 2), before anything runs."""
    doc = yaml.safe_load(EXAMPLE.read_text())
    doc["tracker"].update({"certificate_date": "2018-12-31", "certificate_due": "2019-12-31", key: value})
    path = tmp_path / "hw.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=message) as exc:
        load_hardware(path)
    assert f"tracker.{key}" in str(exc.value) and "\n" not in str(exc.value)

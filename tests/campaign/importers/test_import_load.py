"""The import map's `load` role: the payload mounted at each row, written to the table's load_kg column (what
payload_compliance reads, calib/diagnose/extensions.py); a load that is no number or is negative is one line."""

import pytest

from trackcal.calib.diagnose.extensions import LOAD_COLUMN
from trackcal.calib.io.table import read_table, write_table
from trackcal.campaign.importers.table_map import ImportMapError, import_table, load_map

MAP = """columns:
  joints: [A1, A2]
  xyz: [X, Y, Z]
  time: T
  load: Load
"""


def export(tmp_path, loads):
    rows = "\n".join(f"{10 * k},{k},{-k},1,2,3,{m}" for k, m in enumerate(loads))
    (tmp_path / "e.csv").write_text("T,A1,A2,X,Y,Z,Load\n" + rows + "\n")
    (tmp_path / "m.yaml").write_text(MAP)
    return tmp_path / "e.csv", load_map(tmp_path / "m.yaml")


def test_load_column_is_imported_and_survives_the_table(tmp_path):
    path, m = export(tmp_path, [0, 0, 150, 150.5])  # a payload bolted on after the second row
    table = import_table(path, m).table
    assert table.extra[LOAD_COLUMN].astype(float).tolist() == [0.0, 0.0, 150.0, 150.5]
    write_table(table, tmp_path / "t.csv")
    assert read_table(tmp_path / "t.csv").extra[LOAD_COLUMN].astype(float).tolist() == [0.0, 0.0, 150.0, 150.5]


@pytest.mark.parametrize(("load", "said"), [("-5", "a load is >= 0 kg"), ("heavy", "not a number")])
def test_a_bad_load_is_one_line_naming_row_and_column(tmp_path, load, said):
    path, m = export(tmp_path, [0, load])
    with pytest.raises(ImportMapError, match=rf"row 3: .*Load.*{said}"):
        import_table(path, m)

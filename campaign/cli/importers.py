"""`trackcal import ipa-ur10`: the IPA UR10 + T-Mac series as a measurement table."""

from __future__ import annotations

from trackcal.calib.io.table import write_table
from trackcal.campaign.importers.ipa_ur10 import IpaFormatError, read_ipa_series
from trackcal.campaign.importers.table_map import ImportMapError, import_table, load_map

# Ceilings of the two numbers the import takes (NaN and inf fail them too): a day between poses, and a lever of
# 10 m, beyond any probe a UR10 carries (the T-Mac's points are 0.1 m from its centre; ur10-tmac expects 100 mm)
MAX_PERIOD_S = 86400.0
MAX_LEVER_MM = 10000.0


def cmd_import_ipa(args) -> int:
    if not 0 < args.period_s <= MAX_PERIOD_S:
        raise IpaFormatError(f"--period-s: must be positive and at most {MAX_PERIOD_S:g} s, got {args.period_s}")
    if not 0 < args.lever_mm <= MAX_LEVER_MM:
        raise IpaFormatError(f"--lever-mm: must be positive and at most {MAX_LEVER_MM:g} mm, got {args.lever_mm}")
    table = read_ipa_series(args.file, station=args.station, period_s=args.period_s,
                            virtual_points=args.virtual_points, lever_mm=args.lever_mm)  # fmt: skip
    try:
        write_table(table, args.out)
    except OSError as exc:
        raise IpaFormatError(f"{args.out}: cannot write ({exc.strerror or exc})") from None
    print(f"{args.file}: {len(set(table.pose))} poses, {len(table)} rows -> {args.out}")
    # the files name no instrument (ABOUT.md of the data set: "a Leica laser tracker"): say which model is assumed
    print("tracker: the files do not say which one measured them; identify and diagnose weigh and judge by the "
          "cell's tracker: key, and ur10-ipa names none, so they assume the Leica AT901 and say so")
    return 0


def cmd_import_table(args) -> int:
    table = import_table(args.files, load_map(args.map))
    try:
        write_table(table, args.out)
    except OSError as exc:
        raise ImportMapError(f"{args.out}: cannot write ({exc.strerror or exc})") from None
    stations = ", ".join(dict.fromkeys(table.station))
    points = ", ".join(dict.fromkeys(table.point))
    print(f"{', '.join(args.files)}: {len(set(table.pose))} poses, {len(table)} rows (stations {stations}; points "
          f"{points}; {table.n_joints} joints) -> {args.out}")
    # a map describes columns, not the instrument: say which noise model the table will be weighed by
    print("tracker: an export does not say which instrument measured it; identify and diagnose weigh and judge by "
          "the cell's tracker: key (the Leica AT901 when the cell names none, and they say so)")
    return 0

"""`trackcal import ipa-ur10`: the IPA UR10 + T-Mac series as a measurement table."""

from __future__ import annotations

from trackcal.calib.io.table import write_table
from trackcal.campaign.importers.holdout import holdout_split
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
    table = read_ipa_series(
        args.file,
        station=args.station,
        period_s=args.period_s,
        virtual_points=args.virtual_points,
        lever_mm=args.lever_mm,
    )
    try:
        write_table(table, args.out)
    except OSError as exc:
        raise IpaFormatError(f"{args.out}: cannot write ({exc.strerror or exc})") from None
    print(f"{args.file}: {len(set(table.pose))} poses, {len(table)} rows -> {args.out}")
    # the files name no instrument (ABOUT.md of the data set: "a Leica laser tracker"): say which model is assumed
    print(
        "tracker: the files do not say which one measured them; identify and diagnose weigh and judge by the "
        "cell's tracker: key, and ur10-ipa names none, so they assume the Leica AT901 and say so"
    )
    return 0


def cmd_import_table(args) -> int:
    if (args.holdout is None) != (args.test_out is None):
        raise ImportMapError(
            "--holdout FRACTION and --test-out FILE go together: the share of poses held out and "
            "the table they are written to"
        )
    imported = import_table(args.files, load_map(args.map), args.joints)
    table = imported.table
    tables = [(table, args.out)]
    if args.holdout is not None:
        train, test = holdout_split(table, args.holdout, args.seed)
        tables = [(train, args.out), (test, args.test_out)]
    for t, out in tables:
        try:
            write_table(t, out)
        except OSError as exc:
            raise ImportMapError(f"{out}: cannot write ({exc.strerror or exc})") from None
    stations = ", ".join(dict.fromkeys(table.station))
    points = ", ".join(dict.fromkeys(table.point))
    files = ([args.joints] if args.joints else []) + args.files
    print(
        f"{', '.join(files)}: {len(set(table.pose))} poses, {len(table)} rows (stations {stations}; points "
        f"{points}; {table.n_joints} joints) -> {args.out if args.holdout is None else 'split below'}"
    )
    skipped = sum(imported.missing.values())
    if skipped:
        each = ", ".join(f"{p} {k} of {imported.rows[p]}" for p, k in imported.missing.items() if k)
        print(f"skipped {skipped} rows without a reading (NaN or empty x, y, z): {each}")
    if args.holdout is not None:
        for t, out, side in ((train, args.out, "training"), (test, args.test_out, "test")):
            print(f"{side}: {len(set(t.pose))} poses, {len(t)} rows -> {out}")
        print(f"held out {args.holdout:g} of the poses, drawn with seed {args.seed}; no pose is in both")
    # a map describes columns, not the instrument: say which noise model the table will be weighed by
    print(
        "tracker: an export does not say which instrument measured it; identify and diagnose weigh and judge by "
        "the cell's tracker: key (the Leica AT901 when the cell names none, and they say so)"
    )
    return 0

"""`trackcal import ipa-ur10`: the IPA UR10 + T-Mac series as a measurement table."""

from __future__ import annotations

from trackcal.calib.io.table import write_table
from trackcal.campaign.importers.ipa_ur10 import IpaFormatError, read_ipa_series


def cmd_import_ipa(args) -> int:
    if not args.period_s > 0:
        raise IpaFormatError(f"--period-s: must be positive, got {args.period_s}")
    table = read_ipa_series(args.file, station=args.station, period_s=args.period_s,
                            virtual_points=args.virtual_points, lever_mm=args.lever_mm)  # fmt: skip
    try:
        write_table(table, args.out)
    except OSError as exc:
        raise IpaFormatError(f"{args.out}: cannot write ({exc.strerror or exc})") from None
    print(f"{args.file}: {len(set(table.pose))} poses, {len(table)} rows -> {args.out}")
    return 0

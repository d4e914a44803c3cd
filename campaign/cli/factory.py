"""`trackcal factory-robot`: the robot config with the controller's own calibration as nominal
(campaign.jobs.factory)."""

from __future__ import annotations

from trackcal.campaign.jobs.factory import factory_robot


def cmd_factory_robot(args) -> int:
    done = factory_robot(args.cell, args.out, conf=args.conf, hardware=args.hardware)
    print(
        f"nominal: the factory calibration of {done.source}, exactly; link lengths changed by up to "
        f"{done.max_length_change_mm:.4f} mm, link rotations by up to {done.max_rotation_change_deg:.4f} deg; robot "
        f"config written to {done.path}"
    )
    return 0

"""Who the mock emScon tracker says it is: the answers to GetTrackerInfo and GetSystemSoftwareVersion, and the serial
number of GetSystemStatus, as one value (the twin's tracker identity).

The fields are those of GetTrackerInfoRT and GetSystemSoftwareVersionRT (beckjac/emscon_ros
include/emscon_ros/ES_C_API_Def.h, TPI V3.6; drivers/emscon/messages.py). The tracker type is the cell's instrument
model (calib.model.instruments) where the header's ES_LTSensorType names it (the AT901 family, the AT401), else
ES_LTS_Undefined with the model in the name; the serial number is a pure function of the twin's seed, so a mock's
hardware file (campaign.cells.sim.hardware_doc) can state it and a test can state another.

Assumed, not read from a datasheet (no stored copy of the AT901's was found): the features (range, data rate,
angle ranges, faces), the LCP firmware 3.6 and the server's software version "3.6.0": only the identity fields are
what trackcal reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from trackcal.drivers.emscon.enums import LTSensorType, ResultStatus, TrkAccuracyModel
from trackcal.drivers.emscon.messages import SetUnits, SoftwareVersionAnswer, TrackerInfoAnswer
from trackcal.mocks.servers.emscon_units import MM_PER_LENGTH, RAD_PER_ANGLE

SERIAL_BASE = 390_000  # the twin's serial numbers: SERIAL_BASE + seed % 10000 (six digits, as an lSerialNumber)
# the instrument models (calib.model.instruments keys) that ES_LTSensorType names [H]
SENSOR_TYPES = {"AT901": LTSensorType.AT901_LR, "AT401": LTSensorType.AT401}


@dataclass(frozen=True)
class TrackerIdentity:
    """The mock tracker's identity: its type, name, serial number, LCP firmware and server software version."""

    tracker_type: LTSensorType = LTSensorType.AT901_LR
    name: str = "AT901-LR"
    serial_number: int = SERIAL_BASE
    lcp_firmware: tuple[int, int] = (3, 6)
    software: str = "3.6.0"
    compensation_id: int = 1

    def tracker_info(self, units: SetUnits) -> TrackerInfoAnswer:
        """GetTrackerInfoRT of this tracker, its lengths and angles in the `units` set (SetUnits)."""
        mm, deg = MM_PER_LENGTH[units.length], math.radians(1.0) / RAD_PER_ANGLE[units.angle]
        return TrackerInfoAnswer(
            ResultStatus.ALL_OK,
            self.tracker_type,
            self.name,
            self.serial_number,
            self.compensation_id,
            True,
            True,
            True,
            0.0,
            80_000.0 / mm,
            0.0,
            3000,
            2,
            360.0 * deg,
            145.0 * deg,
            TrkAccuracyModel.TAM_2005,
            self.lcp_firmware,
        )

    def software_version(self) -> SoftwareVersionAnswer:
        return SoftwareVersionAnswer(ResultStatus.ALL_OK, self.software)


DEFAULT_IDENTITY = TrackerIdentity()


def twin_identity(model_key: str, seed: int) -> TrackerIdentity:
    """The twin's tracker: the cell's instrument model (its calib.model.instruments key) and a serial number of the
    seed."""
    kind = SENSOR_TYPES.get(model_key, LTSensorType.UNDEFINED)
    name = "AT901-LR" if kind == LTSensorType.AT901_LR else (model_key or "custom")[:31]
    return TrackerIdentity(kind, name, SERIAL_BASE + seed % 10_000)

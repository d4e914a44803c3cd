"""Model discovery beyond the geometric model: `diagnose` (`calib.diagnose.diagnosis`)."""

from trackcal.calib.diagnose.diagnosis import Diagnosis, diagnose

__all__ = ["Diagnosis", "diagnose"]

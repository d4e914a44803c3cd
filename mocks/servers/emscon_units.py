"""What the mock tracker does with units and coordinate system types: its internal values (mm, radians,
degrees Celsius, hPa, Cartesian right-handed) to and from what SetUnits / SetCoordinateSystemType select.

Unit factors are exact by definition where they can be: 1 yd = 0.9144 m, 1 ft = 1/3 yd, 1 in = 1/36 yd
(international yard, 1959); 400 gon = 2 pi rad; degF = degC * 9/5 + 32; 1 hPa = 1 mbar = 0.1 kPa. The other
pressure units are conventional, NIST SP 811 (2008) appendix B.8: 1 mmHg = 133.3224 Pa, 1 psi = 6894.757 Pa,
1 inH2O = 249.0889 Pa, 1 inHg = 3386.389 Pa.

Coordinate system types: ES_C_API_Def.h and Enum.h (beckjac/emscon_ros) name them (ES_CS_RHR, LHRX, LHRY,
LHRZ, CCW, CCC, SCW, SCC) without defining them. Assumed here, from the names: RHR right-handed rectangular;
LHRX/Y/Z left-handed rectangular, the named axis mirrored; CCW/CCC cylindrical (horizontal angle clockwise /
counter-clockwise from +x, horizontal radius, height z); SCW/SCC spherical (horizontal angle as for CC*,
zenith angle from +z, distance), in the order MuffinSpawn/Leica bin/command-example.py prints an ES_CS_SCC
result (dVal1 theta, dVal2 phi, dVal3 r). Standard deviations follow their value: a length, or for an angle
the length deviation over the distance.
"""

from __future__ import annotations

import math

from trackcal.drivers.emscon.enums import (
    AngleUnit,
    CoordinateSystemType,
    LengthUnit,
    PressureUnit,
    TemperatureUnit,
)
from trackcal.drivers.emscon.messages import SetUnits

MM_PER_LENGTH = {
    LengthUnit.METER: 1000.0,
    LengthUnit.MILLIMETER: 1.0,
    LengthUnit.MICRON: 1e-3,
    LengthUnit.FOOT: 304.8,
    LengthUnit.YARD: 914.4,
    LengthUnit.INCH: 25.4,
}
RAD_PER_ANGLE = {AngleUnit.RADIAN: 1.0, AngleUnit.DEGREE: math.pi / 180.0, AngleUnit.GON: math.pi / 200.0}
HPA_PER_PRESSURE = {
    PressureUnit.MBAR: 1.0,
    PressureUnit.HPASCAL: 1.0,
    PressureUnit.KPASCAL: 10.0,
    PressureUnit.MMHG: 1.333224,
    PressureUnit.PSI: 68.94757,
    PressureUnit.INH2O: 2.490889,
    PressureUnit.INHG: 33.86389,
}
_MIRROR = {CoordinateSystemType.LHRX: 0, CoordinateSystemType.LHRY: 1, CoordinateSystemType.LHRZ: 2}
_CYLINDRICAL = (CoordinateSystemType.CCW, CoordinateSystemType.CCC)
_SPHERICAL = (CoordinateSystemType.SCW, CoordinateSystemType.SCC)
_CLOCKWISE = (CoordinateSystemType.CCW, CoordinateSystemType.SCW)
Vec = tuple[float, float, float]


def angular(cs: CoordinateSystemType) -> tuple[bool, bool, bool]:
    """Which of the three values of type `cs` are angles (the others are lengths)."""
    if cs in _CYLINDRICAL:
        return True, False, False
    if cs in _SPHERICAL:
        return True, True, False
    return False, False, False


def to_type(cs: CoordinateSystemType, xyz_mm: Vec) -> Vec:
    """Cartesian right-handed mm -> the three values of type `cs` (mm, radians)."""
    x, y, z = xyz_mm
    if cs in _MIRROR:
        v = [x, y, z]
        v[_MIRROR[cs]] = -v[_MIRROR[cs]]
        return v[0], v[1], v[2]
    if cs == CoordinateSystemType.RHR:
        return x, y, z
    hz = math.atan2(y, x)
    hz = -hz if cs in _CLOCKWISE else hz
    rho = math.hypot(x, y)
    if cs in _CYLINDRICAL:
        return hz, rho, z
    return hz, math.atan2(rho, z), math.hypot(rho, z)


def from_type(cs: CoordinateSystemType, values: Vec) -> Vec:
    """The inverse of `to_type`."""
    a, b, c = values
    if cs in _MIRROR or cs == CoordinateSystemType.RHR:
        return to_type(cs, values)  # a mirror is its own inverse
    hz = -a if cs in _CLOCKWISE else a
    rho, z = (b, c) if cs in _CYLINDRICAL else (c * math.sin(b), c * math.cos(b))
    return rho * math.cos(hz), rho * math.sin(hz), z


def to_units(units: SetUnits, cs: CoordinateSystemType, values: Vec) -> Vec:
    """Values of type `cs` in mm / radians -> in the selected length and angle units."""
    mm, rad = MM_PER_LENGTH[units.length], RAD_PER_ANGLE[units.angle]
    a, b, c = (v / (rad if ang else mm) for v, ang in zip(values, angular(cs), strict=True))
    return a, b, c


def from_units(units: SetUnits, cs: CoordinateSystemType, values: Vec) -> Vec:
    """The inverse of `to_units`."""
    mm, rad = MM_PER_LENGTH[units.length], RAD_PER_ANGLE[units.angle]
    a, b, c = (v * (rad if ang else mm) for v, ang in zip(values, angular(cs), strict=True))
    return a, b, c


def stds_to_units(units: SetUnits, cs: CoordinateSystemType, stds_mm: Vec, distance_mm: float) -> Vec:
    """Per-coordinate standard deviations (mm) as values of type `cs` in the selected units."""
    ang = angular(cs)
    values = tuple(s / distance_mm if a else s for s, a in zip(stds_mm, ang, strict=True))
    return to_units(units, cs, values)  # type: ignore[arg-type]


def temperature_to_units(units: SetUnits, celsius: float) -> float:
    return celsius * 9.0 / 5.0 + 32.0 if units.temperature == TemperatureUnit.FAHRENHEIT else celsius


def temperature_from_units(units: SetUnits, value: float) -> float:
    return (value - 32.0) * 5.0 / 9.0 if units.temperature == TemperatureUnit.FAHRENHEIT else value


def pressure_to_units(units: SetUnits, hpa: float) -> float:
    return hpa / HPA_PER_PRESSURE[units.pressure]


def pressure_from_units(units: SetUnits, value: float) -> float:
    return value * HPA_PER_PRESSURE[units.pressure]

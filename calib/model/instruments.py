"""The cell's laser tracker: named instrument models and `custom`, as one-sigma radial and transverse terms.

A tracker measures a point by its range (interferometer or ADM) and two angles (encoders). Its noise is then
radial sigma_r (+ a small part growing with the range) along the beam and transverse sigma_t + k * range across it
(calib.identify.noise.TrackerNoise turns these numbers into covariances and weights).

How a datasheet figure becomes a one-sigma term (every model below says which kind its source gives):
- MPE (maximum permissible error, ASME B89.4.19-2006 / ISO 10360-10): Leica states that "typical results are half
  of the MPE" (AT960 datasheet; AT500 user manual 2.8.1: "Typical measurement results of the Absolute Tracker are
  half of the relevant MPE values"), i.e. MPE = 2 sigma: sigma = MPE / 2.
- a figure stated as 2 sigma (k = 2, "95 %"): sigma = figure / 2; a "typical" one-sigma figure: taken as is.
- the transverse term is the angle encoders' error at the reflector: the datasheet's "angular accuracy" a + b/m, in
  micrometres (a at zero range, b per metre of range), so sigma_t = a/2 + (b/2) * range.
- the radial term is the distance meter's (ADM/IFM) "distance accuracy" c (+ d per metre): sigma_r = c/2 (+ d/2 per m).
- only makers' figures that could be read in a stored copy of their documents are here; any other tracker is a
  `custom` one, with the one-sigma figures of its own datasheet or certificate (a FARO Vantage or an API Radian, for
  instance: their sheets could not be checked when these models were written).

A cell names its tracker as `tracker: {model: AT960}` or `tracker: {model: custom, radial_um: 5, transverse_um: 7.5,
transverse_um_per_m: 3}` (one-sigma values, micrometres; `radial_um_per_m` optional). A cell that names none gets
DEFAULT (the AT901, trackcal's first tracker) and every output says that it was assumed.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from trackcal.calib.errors import CalibError
from trackcal.calib.io import fields


class InstrumentError(CalibError):
    """A tracker model that does not exist or a custom one with impossible numbers."""


@dataclass(frozen=True)
class Instrument:
    """One tracker's one-sigma noise terms (mm, mm per m of range) and where they come from."""

    key: str  # what the cell's `tracker: {model: KEY}` says: a key of MODELS or "custom"
    name: str  # for people: "Leica AT960", "custom tracker"
    radial_mm: float
    transverse_mm: float
    transverse_mm_per_m: float
    radial_mm_per_m: float = 0.0
    source: str = ""
    assumed: bool = False  # True: the cell named no tracker and this one was assumed

    def describe(self) -> str:
        """One phrase for the console and reports: "Leica AT960" or "Leica AT901 (assumed: the cell names no
        tracker)"."""
        return f"{self.name} (assumed: the cell names no tracker)" if self.assumed else self.name

    def to_doc(self) -> dict:
        """What model.json and summaries keep of it (micrometres, one sigma)."""
        return {
            "model": self.key,
            "name": self.name,
            "assumed": self.assumed,
            "radial_um": round(self.radial_mm * 1000, 6),
            "radial_um_per_m": round(self.radial_mm_per_m * 1000, 6),
            "transverse_um": round(self.transverse_mm * 1000, 6),
            "transverse_um_per_m": round(self.transverse_mm_per_m * 1000, 6),
        }


def _from_mpe(
    key: str,
    name: str,
    radial_um: float,
    transverse_um: float,
    transverse_um_per_m: float,
    radial_um_per_m: float = 0.0,
    source: str = "",
) -> Instrument:
    """An instrument from MPE (= 2 sigma) figures in micrometres."""
    return Instrument(
        key, name, radial_um / 2000, transverse_um / 2000, transverse_um_per_m / 2000, radial_um_per_m / 2000, source
    )


MODELS: dict[str, Instrument] = {
    # Leica AT901 (trackcal's numbers since its first release, unchanged): point MPE 15 um + 6 um/m from the
    # angles, distance MPE 10 um; Leica states MPE = 2 sigma -> 5 um radial, 7.5 um + 3 um/m transverse.
    "AT901": _from_mpe(
        "AT901", "Leica AT901", 10, 15, 6, source="Leica Absolute Tracker AT901 datasheet (MPE, ASME B89.4.19)"
    ),
    # Leica AT960: "Angle accuracy +-15 um + 6 um/m", "Dynamic lock-on +-10 um" (distance), "All accuracies are
    # specified as maximum permissible errors (MPE) and calculated per ASME B89.4.19-2006 and draft ISO 10360-10
    # ... Typical results are half of MPE" (Leica Absolute Tracker AT960 datasheet, as reproduced in Journal of
    # Robotics 2021, article 9995787, Table 1: https://www.hindawi.com/journals/jr/2021/9995787/tab1/).
    # The same terms as the AT901.
    "AT960": _from_mpe(
        "AT960", "Leica AT960", 10, 15, 6, source="Leica Absolute Tracker AT960 datasheet (MPE, ASME B89.4.19)"
    ),
    # Leica AT500: "Absolute Distance Meter (ADM) e_ADM +-10 um + 0.3 um/m", "Transverse e_T +-15 um + 6 um/m", as MPE
    # per ISO 10360-10:2021 Annex D, "Typical measurement results of the Absolute Tracker are half of the relevant MPE
    # values" (Leica AT500 User Manual, 2.8.1-2.8.2: https://www.manualslib.com/manual/2861259/Leica-At500.html?page=39).
    # Its R0 parameter (e_R0 +-5 um) is the ADM's zero offset, one constant per instrument that the station's
    # translation absorbs, not noise: left out.
    "AT500": _from_mpe(
        "AT500",
        "Leica AT500",
        10,
        15,
        6,
        radial_um_per_m=0.3,
        source="Leica AT500 User Manual 2.8.2 (MPE, ISO 10360-10:2021)",
    ),
}
DEFAULT = "AT901"
CUSTOM_KEYS = ("radial_um", "transverse_um", "transverse_um_per_m", "radial_um_per_m")


def named(name: str, where: str = "tracker") -> Instrument:
    """A named model (case-insensitive)."""
    key = {k.lower(): k for k in MODELS}.get(name.lower())
    if key is None:
        raise InstrumentError(
            f"{where}.model: {name!r} is no tracker model; choose one of "
            f"{', '.join(MODELS)} or custom (with radial_um, transverse_um, transverse_um_per_m)"
        )
    return MODELS[key]


def assumed() -> Instrument:
    """The model of a cell that names none (DEFAULT), marked as assumed."""
    m = MODELS[DEFAULT]
    return replace(m, assumed=True)


def instrument_from_doc(doc, where: str = "tracker") -> Instrument:
    """The cell's `tracker:` value: a mapping with `model` (a name of MODELS or custom); None: assumed()."""
    if doc is None:
        return assumed()
    if isinstance(doc, str):  # `tracker: AT960`, the short form
        doc = {"model": doc}
    doc = fields.mapping(doc, f"{where} ({{model: NAME}} or {{model: custom, radial_um: .., ...}})", InstrumentError)
    model = fields.text(doc.get("model"), f"{where}.model", InstrumentError)
    if model.lower() != "custom":
        extra = sorted(set(doc) - {"model"})
        if extra:
            raise InstrumentError(
                f"{where}: {', '.join(map(str, extra))}: only a custom tracker takes its own numbers (model: custom)"
            )
        return named(model, where)
    unknown = sorted(set(doc) - {"model", *CUSTOM_KEYS})
    if unknown:
        raise InstrumentError(
            f"{where}: {', '.join(map(str, unknown))}: not a custom tracker key; "
            f"the keys are {', '.join(CUSTOM_KEYS)} (one sigma, micrometres)"
        )
    um = {}
    for key in CUSTOM_KEYS:
        if key not in doc and key != "radial_um_per_m":
            raise InstrumentError(
                f"{where}.{key}: missing (a custom tracker needs radial_um, transverse_um and "
                f"transverse_um_per_m, one sigma in micrometres)"
            )
        um[key] = fields.number(doc.get(key, 0.0), f"{where}.{key}", InstrumentError)
        if um[key] < 0:
            raise InstrumentError(f"{where}.{key}: a standard deviation cannot be negative, got {um[key]:g}")
    for key in ("radial_um", "transverse_um"):
        if um[key] == 0:
            raise InstrumentError(f"{where}.{key}: must be positive (a tracker without noise cannot weigh its points)")
    return Instrument(
        "custom",
        "custom tracker",
        um["radial_um"] / 1000,
        um["transverse_um"] / 1000,
        um["transverse_um_per_m"] / 1000,
        um["radial_um_per_m"] / 1000,
        "the cell's own figures (one sigma)",
    )

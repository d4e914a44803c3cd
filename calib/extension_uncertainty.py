"""The uncertainty a model's extension adds at a TCP: its parameters' covariance (model.json's "extension_covariance",
the fit's as for the geometric parameters) through the TCP's sensitivity to them (issue 38).

Only the causes a compensation applies statically as joint offsets (calib.compensate.STATIC_JOINT_CAUSES: the
commanded joints q give the true ones q + Phi(q) theta) enter: the TCP moves by J_q(q) Phi(q) d theta, J_q the TCP's
joint Jacobian, Phi the extension's joint features at q (the same `build_parts` features compensate uses). The other
causes are not compensated (backlash, a drift in time: their warnings say so) or act on the measurement, not the robot.
Their first-order TCP covariance with the geometric parameters p is

    [J_p, J_q Phi] [[C_pp, C_pe], [C_ep, C_ee]] [J_p, J_q Phi]^T

with the cross term C_pe ("with_parameters"): the fit estimates p and theta together, and they are correlated (a joint
compliance and a joint offset both turn a link). A model written before the extension's covariance was recorded has
none: the figure then holds the geometric parameters' alone, as it did.
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.compensate import STATIC_JOINT_CAUSES
from trackcal.calib.diagnose.extensions import build_parts
from trackcal.calib.errors import CalibError
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.extension import UNIT_FACTORS
from trackcal.calib.model_file import Model

KEY = "extension_covariance"


class ExtensionCovarianceError(CalibError):
    """A model.json "extension_covariance" that does not fit the model's extension."""


def static_names(model: Model) -> list[str]:
    """The parameters of the extension's statically compensated joint causes, in the extension's order."""
    return [n for c, names in model.parts() if c in STATIC_JOINT_CAUSES for n in names]


def joint_features(model: Model, q: np.ndarray) -> np.ndarray:
    """(N, n, e) rad per internal unit: d(true joints)/d(theta) of the static joint causes at commanded joints q (N, n)
    rad, e = len(static_names(model))."""
    static = [(c, names) for c, names in model.parts() if c in STATIC_JOINT_CAUSES]
    if not static or len(q) == 0:
        return np.zeros((len(q), model.chain.dof, 0))
    rows = MeasurementTable(
        seq=np.arange(len(q)),
        t_s=np.zeros(len(q)),
        pose=["c"] * len(q),
        station=["-"] * len(q),
        point=["-"] * len(q),
        q_deg=np.degrees(q),
        xyz=None,
        source="filter targets",
    )
    ext = build_parts(static, model.chain, rows, model.arcs(), forms=model.forms())
    return ext.joint_features.dense()


def _matrix(v, shape: tuple[int, int], where: str) -> np.ndarray:
    try:
        m = np.array(v, dtype=float)
    except (TypeError, ValueError):
        raise ExtensionCovarianceError(f"{KEY}.{where}: expected a matrix of numbers") from None
    if m.shape != shape or not np.all(np.isfinite(m)):
        raise ExtensionCovarianceError(
            f"{KEY}.{where}: expected {shape[0]} x {shape[1]} finite numbers, got shape {m.shape}"
        )
    return m


def extension_covariance(
    model: Model, param_scale: np.ndarray, param_rows: list[int | None]
) -> tuple[np.ndarray, np.ndarray] | None:
    """(C_ee (e, e), C_pe (k, e)) in internal units of the static causes' parameters (`static_names`), with the
    model's k parameters (`param_rows`: each one's row of covariance_order, None when absent; `param_scale`: its
    boundary -> internal factor); None without a recorded extension covariance or static cause."""
    entry, names = model.doc.get(KEY), static_names(model)
    if entry is None or not names:
        return None
    if not isinstance(entry, dict) or not isinstance(entry.get("order"), list):
        raise ExtensionCovarianceError(f"{KEY}: expected {{order, matrix, with_parameters}}")
    order = [str(n) for n in entry["order"]]
    missing = [n for n in names if n not in order]
    if missing:
        raise ExtensionCovarianceError(f"{KEY}.order: {missing[0]!r}, a parameter of the extension, is missing")
    n_params = len(model.doc.get("covariance_order") or [])
    full = _matrix(entry.get("matrix"), (len(order), len(order)), "matrix")
    cross = _matrix(entry.get("with_parameters"), (n_params, len(order)), "with_parameters")
    pars = model.doc["extension"]["parameters"]
    f = np.array([UNIT_FACTORS[pars[n]["unit"]] for n in names])  # internal = boundary / f
    sel = [order.index(n) for n in names]
    c_ee = full[np.ix_(sel, sel)] / np.outer(f, f)
    c_pe = np.zeros((len(param_rows), len(names)))
    have = [i for i, r in enumerate(param_rows) if r is not None]
    c_pe[have] = cross[np.ix_([param_rows[i] for i in have], sel)]  # type: ignore[misc]
    return c_ee, c_pe * np.outer(param_scale, 1.0 / f)

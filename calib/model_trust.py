"""Whether a model.json may move a robot: its digest, its physics and its usability (issues 35 and 42).

- **Digest.** Every model trackcal writes is `sealed`: `digest` is the sha256 of the canonical JSON (keys sorted, no
  spaces, UTF-8) of everything else in the document, which includes `table_sha256`, the sha256 of the table file it
  was identified from (when it was read from a file). A model whose digest does not match its content was edited
  after it was written: `check_digest` refuses it (EditedModelError) unless the caller accepts edits. A model without
  a digest was written before models were sealed: it is accepted with one warning line (old files exist, and tests
  carry model fixtures), its content unchecked.
- **Physics**, whatever the digest says (`check_physics`): every parameter's unit is the one its kind has (a length
  in mm, an angle in deg), every deviation within the chain's physical bounds (calib.model.plausible), and the
  covariance, when there is one, symmetric positive semi-definite. Each refusal is one line naming the file and the
  field.
- **Usability** (`usability`): a model whose parameters the table did not determine (`poorly_determined`,
  calib.identify.determined), whose predicted TCP uncertainty at the test pose (`test_pose`, when the model carries
  it) exceeds the uncalibrated robot's error (`residuals.before.dist_rms_mm`: the nominal robot, stations and points
  fitted to the same table), or with an implausible deviation is unusable: `sealed` writes `"usable": false` and
  `"unusable_why"`, and compensate refuses it unless asked to accept it.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

from trackcal.calib.model.plausible import implausible
from trackcal.calib.model_file import Model, ModelError, model_from_doc

DIGEST_KEY = "digest"
# the keys `test_pose` may give the TCP's standard uncertainty at the test pose under (mm), first found wins
TEST_POSE_SIGMA_KEYS = ("sigma_mm", "tcp_sigma_mm", "uncertainty_mm", "u_mm", "std_mm")
# a covariance is symmetric positive semi-definite up to this, relative to its standard deviations (its correlation
# matrix's smallest eigenvalue may be this far below zero: JSON carries 17 significant digits, the solver's
# covariance is symmetric to ~1e-15)
COVARIANCE_RTOL = 1e-8


class EditedModelError(ModelError):
    """A model whose digest does not match its content."""


def _normalised(doc: dict) -> dict:
    """`doc` as its JSON file holds it (tuples as lists, numpy floats as floats)."""
    return json.loads(json.dumps(doc, allow_nan=False))


def content_digest(doc: dict) -> str:
    """sha256 of the canonical JSON of `doc` without its digest."""
    body = {k: v for k, v in _normalised(doc).items() if k != DIGEST_KEY}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def test_pose_sigma_mm(doc: dict) -> float | None:
    """The TCP's standard uncertainty at the test pose the model states (its `test_pose` entry), None without one."""
    entry = doc.get("test_pose")
    if isinstance(entry, (int, float)) and not isinstance(entry, bool):
        return float(entry)
    if not isinstance(entry, dict):
        return None
    for key in TEST_POSE_SIGMA_KEYS:
        v = entry.get(key)
        if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v):
            return float(v)
    return None


def uncalibrated_error_mm(doc: dict) -> float | None:
    """The uncalibrated robot's error on the model's table: the RMS distance of the nominal robot's residuals (its
    stations and points fitted to the same table), None when the model does not record it."""
    v = (doc.get("residuals") or {}).get("before", {}).get("dist_rms_mm")
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def _values(model: Model) -> np.ndarray:
    return np.array([v if p.is_length else np.degrees(v) for p, v in zip(model.params, model.dev, strict=True)])


def usability(doc: dict) -> str | None:
    """Why the model must not be used to compensate a robot, in one phrase; None when it may."""
    reasons = []
    bad = doc.get("poorly_determined") or {}
    if bad:
        reasons.append(
            f"{len(bad)} parameter(s) poorly determined by its table ({', '.join(bad)}): their values are "
            "whatever the noise makes them"
        )
    sigma, before = test_pose_sigma_mm(doc), uncalibrated_error_mm(doc)
    if sigma is not None and before is not None and sigma > before:
        reasons.append(
            f"its predicted TCP uncertainty at the test pose, {sigma:.3f} mm, exceeds the uncalibrated "
            f"robot's error, {before:.3f} mm"
        )
    try:
        model = model_from_doc(doc)
    except ModelError:
        model = None
    if model is not None:
        wild = implausible(model.chain, model.params, _values(model))
        if wild:
            reasons.append("implausible deviations: " + "; ".join(wild))
    return "; ".join(reasons) or None


def sealed(doc: dict) -> dict:
    """The document as trackcal writes it: its usability judged (`usable`, and `unusable_why` when it is not) and
    its digest last."""
    out = {k: v for k, v in doc.items() if k not in (DIGEST_KEY, "usable", "unusable_why")}
    why = usability(out)
    out["usable"] = why is None
    if why is not None:
        out["unusable_why"] = why
    out[DIGEST_KEY] = content_digest(out)
    return out


def unusable_why(doc: dict) -> str | None:
    """Why a model read from a file is unusable: what it says (`unusable_why`), else what `usability` finds now (a
    model written before usability was recorded); None when it is usable."""
    if doc.get("usable") is False:
        return str(doc.get("unusable_why") or "marked unusable")
    return usability(doc)


def check_digest(doc: dict, source: str, accept_edited: bool = False) -> str | None:
    """None when the digest matches; one warning line for a model without a digest or an edited one that is accepted;
    EditedModelError for an edited one otherwise."""
    stated = doc.get(DIGEST_KEY)
    if stated is None:
        return (
            f"{source}: no digest (written before trackcal sealed its models): its content cannot be checked "
            "against what was identified"
        )
    if stated == content_digest(doc):
        return None
    if accept_edited:
        return f"{source}: its digest does not match its content (edited by hand): used as asked"
    raise EditedModelError(f"{source}: its digest does not match its content: edited by hand?")


def _check_units(model: Model, source: str) -> None:
    for p in model.params:
        unit = model.doc["parameters"][p.name].get("unit")
        expected = "mm" if p.is_length else "deg"
        if unit != expected:
            kind = "a length" if p.is_length else "an angle"
            raise ModelError(f"{source}: parameters.{p.name}.unit: {p.name} is {kind}, in {expected}, not {unit!r}")


def _check_covariance(model: Model, source: str) -> None:
    doc = model.doc
    if doc.get("covariance") is None:
        return
    order = doc.get("covariance_order")  # its type checked by model_from_doc
    if order is None:
        raise ModelError(f"{source}: covariance_order: expected the list of the covariance's parameter names")
    try:
        cov = np.array(doc["covariance"], dtype=float)
    except (TypeError, ValueError):
        raise ModelError(f"{source}: covariance: expected a square matrix of numbers") from None
    cov = cov.reshape(0, 0) if cov.size == 0 else cov  # JSON's [] is the 0 x 0 matrix of a model of no parameter
    if cov.shape != (len(order), len(order)) or not np.all(np.isfinite(cov)):
        raise ModelError(
            f"{source}: covariance: expected a {len(order)} x {len(order)} matrix of finite numbers "
            f"(covariance_order), got shape {cov.shape}"
        )
    var = np.diag(cov)
    if np.any(var < 0):
        i = int(np.argmin(var))
        raise ModelError(
            f"{source}: covariance: the variance of {order[i]} is negative ({var[i]:.4g}): not positive semi-definite"
        )
    sd = np.sqrt(var)
    scale = np.where(sd > 0, sd, 1.0)
    corr = cov / np.outer(scale, scale)
    asym = np.abs(corr - corr.T)
    if asym.max(initial=0.0) > COVARIANCE_RTOL:
        i, j = np.unravel_index(int(np.argmax(asym)), asym.shape)
        raise ModelError(
            f"{source}: covariance: not symmetric ({order[i]}, {order[j]}: {cov[i, j]:.6g} against {cov[j, i]:.6g})"
        )
    low = float(np.linalg.eigvalsh(0.5 * (corr + corr.T)).min(initial=0.0)) if len(corr) else 0.0
    if low < -COVARIANCE_RTOL * max(1.0, float(np.abs(corr).max(initial=0.0))):
        raise ModelError(
            f"{source}: covariance: not positive semi-definite (its correlation matrix has the "
            f"eigenvalue {low:.3g}): no covariance of a fit"
        )


def check_physics(model: Model, source: str) -> None:
    """ModelError, one line naming `source` and the field, for a wrong unit, an implausible deviation or a
    covariance that is not symmetric positive semi-definite."""
    _check_units(model, source)
    wild = implausible(model.chain, model.params, _values(model))
    if wild:
        name = wild[0].split(" ", 1)[0]
        raise ModelError(
            f"{source}: parameters.{name}: {wild[0]} (the chain's physical bound: "
            "calib/model/plausible.py); not a calibration of this robot"
        )
    _check_covariance(model, source)

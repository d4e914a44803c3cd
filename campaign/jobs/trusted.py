"""A model.json read to move a robot (predict, compensate, export-urdf, iso9283 plan --model): checked first
(calib.model_trust), each refusal one line that names the option which overrides it, where one does."""

from __future__ import annotations

from trackcal.calib.model_file import Model, load_model
from trackcal.calib.model_trust import EditedModelError, check_digest, check_physics, unusable_why
from trackcal.campaign.errors import OptionError


def trusted_model(path: str, accept_edited: bool = False) -> tuple[Model, list[str]]:
    """(the model, warning lines): refused when its digest does not match its content (unless `accept_edited`), when
    a unit is not its parameter's, a deviation is beyond the chain's physical bounds or the covariance is not
    symmetric positive semi-definite."""
    model = load_model(path)
    try:
        warning = check_digest(model.doc, str(path), accept_edited)
    except EditedModelError as exc:
        raise OptionError("{why} {0} to use it anyway", "accept_edited", why=str(exc)) from None
    check_physics(model, str(path))
    return model, [warning] if warning else []


def usable_model(model: Model, path: str, accept_poor: bool = False) -> list[str]:
    """[] for a usable model, one warning line for an unusable one that is accepted; refused otherwise."""
    why = unusable_why(model.doc)
    if why is None:
        return []
    if not accept_poor:
        raise OptionError("{path}: unusable: {why} ({0} to use it anyway)", "accept_poor", path=path, why=why)
    return [f"{path}: unusable ({why}): used as asked"]

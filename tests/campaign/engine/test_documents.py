"""Every document the engine emits in a campaign matches its schema in campaign/engine/documents.py (issue 37:
"Document schemas", after bluesky's event-model): the keys and their types are written once, there."""

import types
import typing

import pytest

from tests.helpers import feasible_plan, inproc_live
from trackcal.campaign.engine.documents import SCHEMAS
from trackcal.campaign.engine.engine import DOCUMENTS
from trackcal.campaign.jobs.campaign import new_session, run_stored
from trackcal.campaign.session.store import KINDS


def mismatch(value, hint, where: str) -> str | None:
    """Why `value` is not of the type `hint` (None when it is)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is typing.Any:
        return None
    if typing.is_typeddict(hint):
        return schema_mismatch(value, hint, where)
    if origin in (typing.Union, types.UnionType):
        why = [mismatch(value, a, where) for a in args]
        return None if None in why else f"{where}: {value!r} is none of {hint}"
    if hint is type(None):
        return None if value is None else f"{where}: {value!r} is not None"
    if origin is list:
        if not isinstance(value, list):
            return f"{where}: {value!r} is not a list"
        return next((w for k, v in enumerate(value) if (w := mismatch(v, args[0], f"{where}[{k}]"))), None)
    if origin is dict:
        return None if isinstance(value, dict) else f"{where}: {value!r} is not a mapping"
    if hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    elif hint is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    else:
        ok = isinstance(value, hint)
    return None if ok else f"{where}: {value!r} is not {hint.__name__}"


def schema_mismatch(data, schema, where: str) -> str | None:
    if not isinstance(data, dict):
        return f"{where}: not a mapping"
    hints = typing.get_type_hints(schema)
    unknown = set(data) - set(hints)
    missing = schema.__required_keys__ - set(data)
    if unknown or missing:
        return f"{where}: keys {sorted(unknown)} not in {schema.__name__}, {sorted(missing)} missing"
    return next((w for k, v in data.items() if (w := mismatch(v, hints[k], f"{where}.{k}"))), None)


def test_every_document_kind_has_one_schema():
    assert set(DOCUMENTS) == set(SCHEMAS)
    # the store keeps them under these kinds: start as campaign_started, a successful stop as campaign_done
    stored = {"start": "campaign_started", "stop": "campaign_done"}
    assert {stored.get(n, n) for n in SCHEMAS if n != "progress"} == set(KINDS)


@pytest.fixture(scope="module")
def documents(kr270, tmp_path_factory):
    """Every document of an in-process campaign of 3 configurations (station blocks, prompts, drift checks)."""
    seen = []
    store, _ = new_session(
        tmp_path_factory.mktemp("docs") / "s", "kr270", feasible_plan(kr270, 3, seed=5, repeat=1), "sim", 3
    )
    assert run_stored(store, inproc_live(kr270)[1], [seen.append]).exit_status == "success"
    store.close()
    return seen


def test_every_document_of_a_campaign_matches_its_schema(documents):
    names = {d.name for d in documents}
    assert {
        "start",
        "step_started",
        "call",
        "prompt",
        "operator",
        "measurement",
        "step_done",
        "progress",
        "stop",
        "station_fit",
    } <= names
    for k, doc in enumerate(documents):
        why = schema_mismatch(doc.data, SCHEMAS[doc.name], f"document {k} ({doc.name})")
        assert why is None, why

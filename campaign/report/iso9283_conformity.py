"""The conformity statement of the ISO 9283 report: each figure against the customer's tolerance under a stated decision
rule (calib.decision_rule), e.g. `iso9283 compare ... --tolerance AP=0.5,RP=0.1 --decision-rule guarded`."""

from __future__ import annotations

import math
from dataclasses import dataclass

from trackcal.calib.decision_rule import FAIL, NOT_PROVEN, PASS, RULES, decide
from trackcal.calib.iso9283 import Figure, IsoFigures
from trackcal.calib.iso9283_clauses import clause
from trackcal.campaign.errors import OptionError

# the figures a tolerance can be given for (upper limits, mm); AD is signed: its magnitude |AD_P| is compared
TOLERANCED = {"AP": "AP_P", "RP": "RP_l", "vAP": "vAP_P", "AD": "|AD_P|", "RD": "RD"}


@dataclass(frozen=True)
class Verdict:
    session: str
    compensated: bool
    figure: str  # e.g. "AP_P P1"
    key: str  # the tolerance's key, e.g. "AP"
    value_mm: float
    u95_mm: float
    limit_mm: float
    verdict: str  # calib.decision_rule: "pass", "fail" or "not proven"
    guard_mm: float = 0.0  # the rule's guard band w: U under guarded acceptance (nan: no U stated), 0 under simple

    def to_doc(self) -> dict:
        """Strict JSON: with the guard band w, the acceptance limit T - w (a value at or below it passes) and the
        rejection limit T + w (a value above it fails); a number that does not exist is null."""

        def num(v: float) -> float | None:
            return v if math.isfinite(v) else None

        return {
            "session": self.session,
            "compensated": self.compensated,
            "figure": self.figure,
            "clause": clause(self.key),
            "value_mm": self.value_mm,
            "u95_mm": num(self.u95_mm),
            "tolerance_mm": self.limit_mm,
            "guard_band_mm": num(self.guard_mm),
            "acceptance_limit_mm": num(self.limit_mm - self.guard_mm),
            "rejection_limit_mm": num(self.limit_mm + self.guard_mm),
            "verdict": self.verdict,
        }


def parse_tolerances(text: str | None) -> dict[str, float]:
    """'AP=0.5,RP=0.1' (mm) -> {"AP": 0.5, "RP": 0.1}; OptionError (one line) on anything else."""
    if text is None:
        return {}
    out: dict[str, float] = {}
    for part in text.split(","):
        key, eq, number = (s.strip() for s in part.partition("="))
        try:
            limit = float(number) if eq else math.nan
        except ValueError:
            limit = math.nan
        if key not in TOLERANCED or not (math.isfinite(limit) and limit > 0) or key in out:
            raise OptionError(
                "{0}: expected FIGURE=MM,... with FIGURE one of {keys} (each once) and MM a positive "
                "number, got {text!r}",
                "tolerance",
                keys=", ".join(TOLERANCED),
                text=text,
            )
        out[key] = limit
    return out


def _figures(t: IsoFigures, key: str) -> list[tuple[str, Figure]]:
    if key in ("AP", "RP"):
        return [(f"{TOLERANCED[key]} {p.name}", p.ap if key == "AP" else p.rp) for p in t.poses]
    if key == "vAP":
        return [(f"vAP_P {name}", f) for name, f in t.vap.items()]
    f = t.ad if key == "AD" else t.rd
    if f is None:
        return []
    return [(TOLERANCED[key], Figure(abs(f.value), f.u95, f.clause))]


def verdicts(tests: list[IsoFigures], tolerances: dict[str, float], rule: str) -> list[Verdict]:
    """Every toleranced figure of every test, decided under `rule` ("simple" or "guarded")."""
    if rule not in RULES:
        raise OptionError(
            "{0}: expected one of {rules}, got {rule!r}", "decision_rule", rules=", ".join(RULES), rule=rule
        )
    return [
        Verdict(
            t.session,
            t.compensated,
            name,
            key,
            f.value,
            f.u95,
            limit,
            decide(f.value, f.u95, limit, rule),
            f.u95 if rule == "guarded" else 0.0,
        )
        for t in tests
        for key, limit in tolerances.items()
        for name, f in _figures(t, key)
    ]


def conformity_doc(rule: str, tolerances: dict[str, float], found: list[Verdict]) -> dict:
    """The conformity statement of `compare --json`: the rule, its text, the tolerances and every verdict."""
    return {
        "decision_rule": rule,
        "rule": RULES[rule],
        "tolerances_mm": dict(tolerances),
        "verdicts": [v.to_doc() for v in found],
        "counts": {k: sum(v.verdict == k for v in found) for k in (PASS, FAIL, NOT_PROVEN)},
    }

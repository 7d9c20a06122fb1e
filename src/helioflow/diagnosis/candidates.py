"""What the diagnosis tries: changes to the model's effect list, their physical ranges, and the
measurements that tell apart two changes that explain the same residual.

A candidate is one change to one registry effect:

- "add": an effect the model lacks, its parameters fitted (tracking, slope error, camera, ...);
- "free": an effect the model has with fixed values, those values fitted ("your slope error is
  not the 0.5 mrad you assumed");
- "switch": the sun shape replaced by another profile, its width fitted ("your sun is not the
  Gaussian you assumed").

An "add" or "free" candidate can reproduce the model it extends (`neutral`): the added effect at
values that do nothing, the freed values at the model's. A fit of it starts there and keeps that
start when it finds nothing better, so adding a candidate never raises the training loss.
"""

from __future__ import annotations

from dataclasses import dataclass

from helioflow.physics.effects import REGISTRY

ANY_OTHER = "images at sun positions where the two predict different spots"


@dataclass(frozen=True)
class Candidate:
    """One change to the model's effect list (module docstring).

    Attributes:
        label: its name in the ranking: the effect ("tracking") for an added effect, else what
            changes ("sunshape: buie", "slope_error: fit sigma_mrad").
        effect: the registry effect it changes.
        params: that effect's parameters in the changed model ("fit" where fitted).
        change: "add", "free" or "switch".
        neutral: the effect's parameters that reproduce the model (None for a switch).
    """

    label: str
    effect: str
    params: dict
    change: str
    neutral: dict | None


def candidates(effects: dict, n_facets: int, known: frozenset = frozenset()) -> tuple[list[Candidate], list[dict]]:
    """(candidates to try, {effect, reason} not tried) for a model effect list and heliostat: every
    registry effect the model lacks, as its module says it is tried (`Effect.tried_as`), and the
    changes of those it has (`Effect.changed`). `known`: the facts the dataset holds that some
    effects need (`Effect.needs`, e.g. "neighbours")."""
    tried, skipped = [], []
    for name, effect in REGISTRY.items():
        present = name in effects
        if effect.not_applicable or (effect.needs and effect.needs[0] not in known):
            if not present:
                skipped.append({"effect": name, "reason": effect.not_applicable or (effect.needs or ("", ""))[1]})
        elif n_facets < effect.min_facets[0]:
            if not present:
                skipped.append({"effect": name, "reason": effect.min_facets[1]})
        elif not present:
            assert effect.tried_as is not None, f"{name}: an applicable effect says how it is tried"
            tried.append(Candidate(name, name, dict(effect.tried_as), "add", effect.neutral))
        else:
            tried += [Candidate(v.label, name, v.params, v.change, v.neutral)
                      for v in effect.changed(dict(effects[name] or {}))]
    return tried, skipped


def implausible(fitted: dict) -> list[str]:
    """Descriptions of fitted values (keys as `FitResult.fitted_values` summarised: "effect.param",
    tensors as "<name>_rms") outside their physical range (`Effect.plausible`)."""
    out = []
    for key, value in fitted.items():
        effect, _, name = key.partition(".")
        ranges = REGISTRY[effect].plausible if effect in REGISTRY else {}
        rule = ranges.get(name) or ranges.get("*")
        if rule is not None and isinstance(value, (int, float)) and not rule[0] <= abs(value) <= rule[1]:
            out.append(f"{key} = {value:g} ({rule[2]})")
    return out


def separating(a: str, b: str) -> str:
    """The measurement that tells effect `a` from effect `b` (either's `Effect.separated_from`)."""
    return REGISTRY[a].separated_from.get(b) or REGISTRY[b].separated_from.get(a) or ANY_OTHER

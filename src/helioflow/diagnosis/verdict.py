"""The diagnosis' verdict in words: one paragraph that names the missing effect with its evidence,
what it is confounded with and how to tell them apart, the config line that adds it, and what
remains against the noise."""

from __future__ import annotations

from helioflow.diagnosis.candidates import implausible
from helioflow.diagnosis.criteria import NUMERICAL_FLOOR, PARTLY, THRESHOLD, compared_floor
from helioflow.physics.effects import REGISTRY


def verdict(ranking: list[dict], summary: dict, remaining: dict, location: dict, fitted: dict | None = None) -> str:
    """One plain-language paragraph with one of three outcomes: the residual is explained down to
    the noise; a registry effect is found (what, the evidence, how much fitting it helps, what it
    is confounded with and how to tell them apart, implausible fitted values, the config line),
    ending with what remains; or a residual well above the noise remains that no candidate
    explains, with where it lives (`location`: by_sun_position, in_image, on_mirror).

    `fitted`: the named changes' values ("effect.param", tensors as "<key>_rms") at their joint fit,
    the model the config lines make: those are the values judged plausible or not (a change's fit
    alone, before the others are added, may bend to mimic them: a surface alone takes up a tracking
    error)."""
    meaningful = [r for r in ranking if r["meaningful"]]
    if not meaningful:
        error, ratio = remaining["error"], remaining["over_noise"]
        if ranking:
            best = ranking[0]
            change = (f"cuts it by {best['relative_reduction']:.0%}" if best["relative_reduction"] > 0
                      else "does not lower it")
            tried = f"no change to the model cuts it by {THRESHOLD:.0%} or more (the best, {_words(best)}, {change})"
        else:
            tried = "no effect could be tested: the model contains every registry effect that applies here"
        if remaining["explained"]:
            return (f"Explained down to the noise: the model's held-out error (misplaced flux {error:.3f}) is "
                    f"{ratio:.1f} times {_floor_words(remaining)}, and {tried}.")
        partly = ranking and ranking[0]["relative_reduction"] >= PARTLY
        hint = (f"{_words(ranking[0]).capitalize()} explains part of it; an effect the registry lacks may explain "
                "the rest" if partly else "An effect the registry lacks is likely")
        return (f"A residual {ratio:.1f} times the noise remains that no candidate explains: held-out misplaced flux "
                f"{error:.3f}, {ratio:.1f} times {_floor_words(remaining)}, and {tried}. {_lives(location)} {hint}: "
                "see docs/adding_an_effect.md.")
    top = meaningful[0]
    effect = top["changes"]
    evidence = REGISTRY[effect].signature_text.format(**summary)
    if top["change"] == "add":
        lacks = f"The model lacks {REGISTRY[effect].missing_text}"
    elif top["change"] == "switch":
        lacks = f"The model's sun is not the one it assumes: a {top['effect'].split(': ')[1]} sun fits better"
    else:
        lacks = f"The model's fixed {effect.replace('_', ' ')} values are off ({top['effect']})"
    text = (f"{lacks}: {evidence}; fitting it cuts the held-out error by {top['relative_reduction']:.0%} "
            f"(misplaced flux {top['heldout_error_before']:.3f} -> {top['heldout_error_after']:.3f}).")
    if len(meaningful) > 1:
        others = ", ".join(f"{_words(r)} ({_cut_words(r)})" for r in meaningful[1:])
        text += f" Also needed, each added to the changes before it: {others}."
    for r in meaningful:
        for c in r["confounded_with"]:
            given = f"given {', '.join(g.replace('_', ' ') for g in c['given'])}" if c["given"] else "alone"
            r_text = (f"; their parameters correlate at r = {c['correlation']:.2f} at the joint fit"
                      if c.get("correlation") is not None else "")
            text += (f" {_words(r).capitalize()} and {c['effect'].replace('_', ' ')} ({c['relative_reduction']:.0%} "
                     f"{given}) explain the same residual on these images{r_text}: {c['separated_by']} would tell "
                     f"them apart.")
    for flag in implausible(fitted or {}):
        text += f" The fitted {flag} is implausible: it likely stands in for another effect."
    if remaining["explained"]:
        text += (f" What remains (misplaced flux {remaining['error']:.3f}) is {remaining['over_noise']:.1f} times the "
                 "noise: explained down to the noise.")
    else:
        text += (f" Even so, a residual {remaining['over_noise']:.1f} times the noise remains (misplaced flux "
                 f"{remaining['error']:.3f}, against {_floor_words(remaining)}) that no candidate explains. "
                 f"{_lives(location)}")
    lines = "; ".join(f"`{r['config']}`" for r in meaningful)
    return text + f" To add it, put under model.effects in config.yaml: {lines}; rerun, and look again."


def _floor_words(remaining: dict) -> str:
    """What the remaining error is compared with, in words."""
    floor, resolution = remaining["noise_floor"], remaining["model_resolution"]
    if resolution:
        return (f"what noise and the model's own resolution leave ({float(compared_floor(floor, True)):.3f}: the noise "
                f"{floor:.3f}, the model {resolution})")
    if floor < NUMERICAL_FLOOR:
        return (f"the diagnosis' numerical floor ({NUMERICAL_FLOOR}: these images hold almost no noise, "
                f"{floor:.5f})")
    return f"what noise alone leaves on these images ({floor:.3f})"


def _lives(location: dict) -> str:
    """Where the residual lives, in one sentence."""
    parts = [f"against the sun, {location['sun_position']['where']}",
             f"in the image, {location['image']['where']}", f"on the mirror, {location['mirror']['where']}"]
    return "Where it lives: " + "; ".join(parts) + "."


def _words(entry: dict) -> str:
    return entry["effect"].replace("_", " ")


def _cut_words(entry: dict) -> str:
    """How much a needed change cuts the held-out error, and, when it was named for its fitted values
    (`named_for`), how far the images put them from doing nothing (the Wald test) and whether the
    covariance determines them."""
    cut = f"{entry['relative_reduction']:.0%}"
    if entry.get("named_for") != "significance":
        return cut
    test = entry["significance"]
    caveat = ("" if test["determined"] else "; the residual is structured, so the covariance does not determine "
              "its value: it may stand in for what the model lacks")
    return (f"{cut}, too little to count alone, but its fitted values stand away from doing nothing at "
            f"p = {test['p']:.1g} (Wald {test['wald']:.1f}, {test['dof']} degree{'s' * (test['dof'] > 1)} of "
            f"freedom{caveat})")


def model_flags(fitted: dict) -> str:
    """Sentences naming the model's own fitted values (keys "effect.param", as `implausible` takes
    them) outside their physical range, or "": a value the model stretches there (a Buie sun's
    circumsolar ratio at its bound) stands in for what the model lacks, whether or not a candidate
    is named."""
    return "".join(f" The model's own fitted {flag} is implausible: it likely stands in for what the model lacks."
                   for flag in implausible(fitted))

"""The report's diagnosis and error-ledger sections, from diagnosis/<dataset>.json (rule
`diagnose`) and its figures figures/diagnosis/<dataset>_{signatures,ranking,residuals,location,ledger}.png."""

from __future__ import annotations

from pathlib import Path

from helioflow.errors import DataError
from helioflow.report.html import esc, figure, figures_by_name, fmt, nested_tables, read_json, table

FIGURES = (("signatures", "residual signatures against sun position"),
           ("ranking", "ranking of the missing effects"),
           ("residuals", "residual images at the worst sun positions"),
           ("location", "where the remaining residual lives: sun position, spot, mirror"))


def _fitted(params: dict) -> str:
    """'a = 0.5, b = 2' of parameter values (floats to 4 significant digits)."""
    return ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                     for k, v in (params or {}).items())


def _pct(value) -> str:
    return "–" if value is None else f"{round(100 * value):d} %"


def read_diagnosis(path: str) -> dict:
    """A diagnosis JSON with its `dataset` (default: the file's stem); DataError if it has no ranking."""
    data = read_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("ranking"), list):
        raise DataError(f"{path}: not a diagnosis JSON (written by `diagnose`): no `ranking` list")
    data.setdefault("dataset", Path(path).stem)
    return data


def _terms(d: dict) -> str:
    """The model the diagnosis started from, its error measure and its threshold."""
    measure = d.get("error_measure") or {}
    threshold = d.get("threshold")
    if isinstance(threshold, dict):
        threshold = _fitted(threshold)
    elif isinstance(threshold, float):
        threshold = f"relative reduction {_pct(threshold)}"
    return (f"<p>Model effects: <code>{esc(fmt(d.get('model_effects', {})))}</code>. Error measure: "
            f"<strong>{esc(measure.get('name', '?'))}</strong>: {esc(measure.get('description', ''))}. "
            f"A reduction counts from: {esc(threshold)}.</p>")


def _remaining(d: dict) -> str:
    """What remains after the chosen changes, against the noise floor (empty for an older JSON)."""
    r = d.get("remaining")
    if not isinstance(r, dict) or d.get("noise_floor") is None:
        return ""
    changes = ", ".join(r.get("changes") or []) or "none"
    state = "explained down to the noise" if r.get("explained") else "<strong>not explained</strong>"
    floor = ("the floor" if not r.get("model_resolution")
             else f"the floor with the model's own resolution ({fmt(r['model_resolution'])})")
    return (f"<p>Noise floor (misplaced flux that noise alone leaves): {fmt(d['noise_floor'])}. After the chosen "
            f"changes ({esc(changes)}): {fmt(r.get('error'))}, {fmt(r.get('over_noise'))} times {floor}: {state}. "
            f"{esc(d.get('remaining_note', ''))}</p>")


def uncertainty_table(u: dict | None) -> str:
    """How sure the fitted numbers are (models/uncertainty.py's JSON): every scalar with its sigma,
    every tensor's sigma (RMS) and how many of its entries are not determined, the residual's
    structure and the strongest correlations; empty without one."""
    if not isinstance(u, dict) or not isinstance(u.get("scalars"), dict):
        return ""
    rows = [[name, v.get("value"), v.get("sigma"), v.get("unit"), "yes" if v.get("determined") else "no"]
            for name, v in u["scalars"].items()]
    for name, t in (u.get("tensors") or {}).items():
        sigma = [x for x in _flat(t.get("sigma")) if x is not None]
        rms = (sum(x * x for x in sigma) / len(sigma)) ** 0.5 if sigma else None
        rows.append([name, "(per entry)", rms, t.get("unit"),
                     f"{len(sigma) - int(t.get('undetermined') or 0)} of {len(sigma)} entries"])
    pairs = "; ".join(f"{c['a']} ~ {c['b']}: r = {c['r']}" for c in u.get("correlations") or [])
    return (table(["parameter", "fitted", "sigma (RMS for a tensor)", "unit", "determined"], rows)
            + f"<p>Residual structure {fmt(u.get('structure'))} (about 1 for noise; beyond "
              f"{fmt((u.get('structured_beyond') or {}).get('spreads'))} the spreads, beyond "
              f"{fmt((u.get('structured_beyond') or {}).get('facet'))} on a facet its canting and surface are "
              f"not determined). "
              f"{'Strongest correlations: ' + esc(pairs) + '.' if pairs else ''}</p>")


def _flat(values) -> list:
    if isinstance(values, list):
        return [x for v in values for x in _flat(v)]
    return [values]


def _ranking(d: dict) -> str:
    rows = [[i + 1, r.get("effect"), _fitted(r.get("fitted")), r.get("heldout_error_before"),
             r.get("heldout_error_after"), _pct(r.get("relative_reduction")), r.get("identifiable"),
             _named_by(r)]
            for i, r in enumerate(d["ranking"])]
    return table(["rank", "effect", "fitted parameters", "held-out error before", "after",
                  "relative reduction", "identifiable", "named for"], rows)


def _named_by(entry: dict) -> str:
    """Why a selected change is named (the entry's `named_for`): its cut of the held-out error, or its
    fitted values' Wald test; empty for a change not selected."""
    if entry.get("named_for") == "significance":
        test = entry["significance"]
        return f"its fitted values (Wald p = {test['p']:.1g}{'' if test['determined'] else ', value not determined'})"
    return "its cut" if entry.get("meaningful") else ""


def diagnosis_section(files: dict[str, list[str]]) -> str:
    """Per dataset: verdict, error measure, ranking of the missing effects, signatures, figures."""
    named, parts = figures_by_name(files["diagnosis_figures"]), []
    for path in files["diagnosis"]:
        d = read_diagnosis(path)
        name = d["dataset"]
        parts += [f"<h3>{esc(name)}</h3>", f'<p class="verdict">{esc(d.get("verdict", ""))}</p>',
                  _terms(d), _remaining(d), "<h4>Missing effects, best first</h4>", _ranking(d)]
        if d.get("uncertainty"):
            changes = ", ".join(d["uncertainty"].get("changes") or []) or "no change"
            parts += [f"<h4>How sure the final model's numbers are ({esc(changes)})</h4>",
                      uncertainty_table(d["uncertainty"])]
        if d.get("not_tested"):
            rows = [[t.get("effect"), t.get("reason")] for t in d["not_tested"]]
            parts += ["<h4>Not tested</h4>", table(["effect", "reason"], rows)]
        if d.get("signatures"):
            parts += ["<h4>Residual signatures</h4>", nested_tables(d["signatures"])]
        parts += [figure(named[f"{name}_{kind}.png"], f"{name}: {label}")
                  for kind, label in FIGURES if f"{name}_{kind}.png" in named]
    return "\n".join(parts)


def ledger_section(files: dict[str, list[str]]) -> str:
    """Per dataset: held-out error of every model revision on the same measurements, oldest first."""
    named, parts = figures_by_name(files["diagnosis_figures"]), []
    for path in files["diagnosis"]:
        d = read_diagnosis(path)
        name = d["dataset"]
        rows = [[e.get("revision"), str(e.get("model_hash", ""))[:12], e.get("model_effects"),
                 e.get("heldout_error")] for e in d.get("ledger") or []]
        parts += [f"<h3>{esc(name)}</h3>",
                  table(["revision", "model hash", "model effects", "held-out error"], rows)]
        if f"{name}_ledger.png" in named:
            parts.append(figure(named[f"{name}_ledger.png"],
                                f"{name}: held-out error of every model revision"))
    return "\n".join(parts)

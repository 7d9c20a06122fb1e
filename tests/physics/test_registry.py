"""One effect, one module: every module of physics/effects/ declares one effect with all its facts,
and everything derived from the registry (the tracer's physics, the fit's roles, the diagnosis'
candidates, words and separating measurements) covers every entry."""

import sys
import textwrap
from pathlib import Path

import pytest
import torch

import helioflow.physics.effects as effects_package
from helioflow.diagnosis.candidates import ANY_OTHER, candidates, separating
from helioflow.models.physics_fit import OFFSETS, SCALES, FitResult, initial_tensors
from helioflow.physics.effects import REGISTRY, TENSOR_EFFECTS, check_effects, discover, resolve
from helioflow.physics.effects.base import ACTS_ON, FIT, ROLES
from helioflow.physics.heliostat import Heliostat

FOLDER = Path(effects_package.__file__).parent
SUMMARY = {"width": "12.0% wider", "centroid": 1.5, "outside": 0.05, "ratio": 0.9}  # diagnose.summarise's keys


def heliostat(n_facets: int = 4) -> Heliostat:
    return Heliostat(position=torch.zeros(3), mount="juelich", facet_translation=torch.zeros(n_facets, 3),
                     facet_size=torch.ones(n_facets, 2), facet_normal=torch.tensor([[0.0, 0.0, 1.0]] * n_facets),
                     facet_focal_length=None, control_heights=torch.zeros(n_facets, 4, 4),
                     canting_error=torch.zeros(n_facets, 2), tracking_error=torch.zeros(5))


def test_every_module_in_the_folder_is_one_registry_entry_in_its_order():
    modules = sorted(p.stem for p in FOLDER.glob("*.py") if p.stem not in ("__init__", "base"))
    assert sorted(REGISTRY) == modules  # each module is named after the effect it declares
    orders = [e.order for e in REGISTRY.values()]
    assert orders == sorted(orders) and len(set(orders)) == len(orders)


@pytest.mark.parametrize("name", list(REGISTRY))
def test_each_effect_declares_every_fact_the_tracer_the_fit_and_the_diagnosis_use(name):
    e = REGISTRY[name]
    assert e.acts_on in ACTS_ON and e.doc and e.missing_text
    e.signature_text.format(**SUMMARY)  # the verdict can quote it
    for p in e.parameters:
        assert p.role in ROLES, p
        assert (p.role == "choice") == bool(p.choices), p
        if p.array or p.role == "tensor":
            assert e.tensor is not None, f"{name}.{p.name} is a heliostat tensor: the effect needs a TensorRole"
    if e.not_applicable:
        assert e.tried_as is None
    else:
        check_effects({name: e.tried_as}, "tried_as", allow_fit=True)
        assert any(v == FIT for v in e.tried_as.values()) or not e.parameters, "an added effect fits its parameters"
    if e.neutral is not None:
        check_effects({name: e.neutral}, "neutral", allow_fit=True)
    keys = {p.name for p in e.parameters} | {f"{e.tensor.key}_rms" for _ in [0] if e.tensor} | {"*"}
    assert set(e.plausible) <= keys, set(e.plausible) - keys
    for other, words in e.separated_from.items():
        assert other in REGISTRY and other != name and words
        assert REGISTRY[other].separated_from.get(name) in (None, words), "two modules disagree on a pair"
    physics = resolve({name: {k: v for k, v in (e.neutral or {}).items() if v != FIT}}, heliostat(), 1000.0,
                      neighbours=torch.zeros(0, 3))
    assert physics.heliostat.n_facets == 4  # the effect's apply hook runs


def test_the_tables_derived_from_the_registry_cover_every_entry():
    assert SCALES == {(e.name, p.name) for e in REGISTRY.values() for p in e.parameters if p.role == "scale"}
    assert OFFSETS == {(e.name, p.name) for e in REGISTRY.values() for p in e.parameters if p.role == "offset"}
    assert set(TENSOR_EFFECTS) == {n for n, e in REGISTRY.items() if e.tensor is not None}
    # the diagnosis tries every effect a model lacks, or says why not
    tried, skipped = candidates({}, n_facets=4, known=frozenset({"neighbours"}))
    assert {c.effect for c in tried} | {s["effect"] for s in skipped} == set(REGISTRY)
    # every tensor effect starts a fit and reports its values
    fitted = {n: {p.name: FIT for p in e.parameters} for n, e in REGISTRY.items() if e.tensor is not None}
    tensors, masks = initial_tensors(fitted, heliostat())
    assert set(tensors) == set(masks) == set(TENSOR_EFFECTS)
    values = FitResult(fitted, tensors, fitted=[]).fitted_values()
    for name in TENSOR_EFFECTS:
        assert any(k.startswith(f"{name}.") for k in values), name
    # a pair no module names gets the generic measurement
    assert separating("reflectivity", "attenuation") == ANY_OTHER
    assert "target distance" in separating("camera", "slope_error") == separating("slope_error", "camera")


def test_a_module_dropped_in_a_folder_is_an_effect(tmp_path, monkeypatch):
    """Adding an effect is one module: discover() finds it with all its facts, no table edited."""
    package = tmp_path / "more_effects"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "glare.py").write_text(textwrap.dedent('''
        from helioflow.physics.effects.base import FIT, Effect, Parameter

        def apply(build, params):
            build.reflectivity *= 1.0 - params.get("loss", 0.0)

        EFFECT = Effect(name="glare", order=5, acts_on="ray power",
                        parameters=(Parameter("loss", 0.0, 0.0, 1.0, role="scale"),), identifiable=False,
                        doc="a test effect", apply=apply, tried_as={"loss": FIT}, neutral={"loss": 0.0},
                        missing_text="glare", signature_text="the flux is {ratio:.2f} times the model's")
    '''))
    monkeypatch.syspath_prepend(str(tmp_path))
    found = discover(package, "more_effects")
    assert list(found) == ["glare"] and found["glare"].tried_as == {"loss": FIT}
    sys.modules.pop("more_effects.glare", None)
    sys.modules.pop("more_effects", None)

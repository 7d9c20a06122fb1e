"""Config `device` reaches every rule that computes: trace, train, evaluate, diagnose, recovery and
compose_field each resolve the device their rule's spec (or --device) names, and compute there.

On a machine without CUDA the resolver is replaced by one that records what it was asked for and
answers "cpu": the rules then run for real on the CPU, and the record shows that the configured
device got through the command line and the spec to the function that places the tensors.
compose_field's test is in tests/field/test_field_maps.py (it reuses that file's field).
"""

import json
from pathlib import Path

import pytest
import torch

import helioflow.data.synthetic
import helioflow.diagnosis.diagnose
import helioflow.models.registry
from helioflow.cli import main
from helioflow.config import load_config
from helioflow.data.surfaces import HeliostatSpec, true_heliostat, write_heliostat
from helioflow.device import resolve_device
from helioflow.models.registry import load_model
from helioflow.workflow import diagnose_params, evaluate_params, surfaces_params, trace_params, train_params

TINY = Path(__file__).resolve().parent / "workflow" / "tiny_config.yaml"
RESOLVING_MODULES = (helioflow.data.synthetic, helioflow.models.registry, helioflow.diagnosis.diagnose)


@pytest.fixture
def asked(monkeypatch) -> list[str]:
    """The devices the rules asked for, in order; every one is answered with the CPU."""
    record: list[str] = []

    def resolver(device):
        record.append(str(device))
        return torch.device("cpu")

    for module in RESOLVING_MODULES:
        monkeypatch.setattr(module, "resolve_device", resolver)
    return record


@pytest.fixture
def config() -> dict:
    """The tiny config with `device: cuda`, and fits small enough for seconds."""
    config = load_config(TINY)
    config["device"] = "cuda"
    config["networks"] = {"nearest": {}, "drt": {"fit_steps": 3, "rounds": 1, "fit_images": 4, "cells_per_side": 8,
                                                 "gauss_newton_steps": 0}}
    config["diagnosis"] = {"fit_images": 3, "heldout_images": 2, "fit_steps": 2, "rounds": 1, "cells_per_side": 8,
                           "max_effects": 1}
    return config


def test_auto_is_cuda_where_there_is_one_else_the_cpu():
    assert resolve_device("auto") == torch.device("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device("cpu") == torch.device("cpu")


def test_the_configured_device_reaches_every_rule_that_computes(config, asked, tmp_path):
    params = surfaces_params(config, "small")
    spec = HeliostatSpec.from_config(params.pop("name"), params)
    heliostat, dataset = tmp_path / "small.h5", tmp_path / "scan.h5"
    write_heliostat(heliostat, true_heliostat(spec), spec)

    assert main(["trace", "--spec", json.dumps(trace_params(config, "scan")), "--heliostat", str(heliostat),
                 "--output", str(dataset)]) == 0
    assert asked == ["cuda"]

    for network in ("nearest", "drt"):
        model, spec = tmp_path / f"{network}.pt", train_params(config, "scan", network)
        spec["settings"] = {**spec["settings"], "heliostat_path": str(heliostat)} if network == "drt" else {}
        assert main(["train", "--spec", json.dumps(spec), "--dataset", str(dataset),
                     "--output", str(model), "--curve", str(tmp_path / "c.csv"),
                     "--curve-figure", str(tmp_path / "c.png")]) == 0
        assert asked[-1] == "cuda", network
    assert load_model(model)[0].device == torch.device("cpu")  # a model file loads on any device

    del asked[:]
    assert main(["evaluate", "--spec", json.dumps(evaluate_params(config)), "--model", str(model),
                 "--dataset", str(dataset), "--metrics", str(tmp_path / "m.json"),
                 "--per-image", str(tmp_path / "m.csv"), "--grid", str(tmp_path / "g.png"),
                 "--psnr", str(tmp_path / "p.png")]) == 0
    assert asked == ["cuda"]

    del asked[:]
    assert main(["recovery", "--model", str(model), "--heliostat", str(heliostat), "--dataset", str(dataset),
                 "--device", "cuda", "--output", str(tmp_path / "r.json")]) == 0
    assert asked == ["cuda"]

    del asked[:]  # by hand: the figures and the ledger default to names beside the output
    assert main(["diagnose", "--dataset", str(dataset), "--heliostat", str(heliostat),
                 "--output", str(tmp_path / "d.json"), "--spec", json.dumps(diagnose_params(config, "scan"))]) == 0
    assert asked == ["cuda"]
    assert {p.name for p in tmp_path.glob("d_*")} == {"d_ledger.json", "d_signatures.png", "d_ranking.png",
                                                      "d_residuals.png", "d_location.png", "d_ledger-figure.png"}

"""The fitted heliostat written out (heliostats/<dataset>.json): the surface grid is the deformation
the tracer applies, in the heliostat frame as seen facing the mirror; its sigma is the covariance
carried through the B-spline; every fitted value keeps its sigma; a model without heliostat tensors
is refused by name."""

import json

import numpy as np
import pytest
import torch

from helioflow.cli import main
from helioflow.errors import DataError
from helioflow.models.physical import DrtConfig, DrtModel, PhysicsConfig, RaytraceModel
from helioflow.models.physics_fit import FitResult
from helioflow.models.registry import save_model
from helioflow.models.uncertainty import FitUncertainty
from helioflow.physics.heliostat import deformation, ideal_heliostat
from helioflow.scoring.fitted_heliostat import fitted_heliostat, surface_grid

C = 5  # control points per side


def _heights(facets: int) -> torch.Tensor:
    """(F, C, C) control heights (mm) with no symmetry: a wrong axis or row order shows."""
    i, j = np.meshgrid(np.arange(C), np.arange(C), indexing="ij")
    return torch.tensor(np.stack([(f + 1) * (0.3 * i - 0.1 * j**2 + 0.05 * i * j) for f in range(facets)]))


def _surface_names(facets: int) -> list[str]:
    return [f"surface.control_heights_mm[{f}, {i}, {j}]" for f in range(facets) for i in range(C) for j in range(C)]


def test_the_grid_is_the_deformation_the_tracer_applies_rows_from_the_top_columns_to_the_right():
    """A 2 m square facet on a 0.1 m grid: the grid points are the centres of deformation()'s 20 x 20
    cells (rows along up, top first; columns along right), so the two must agree exactly."""
    heliostat = ideal_heliostat(width=2.0, height=2.0, control_points=C).to("cpu", torch.float64)
    heights = _heights(1)
    grid = surface_grid(heliostat, heights, None, 0.1)
    z = deformation(heights, heliostat.facet_size, 20)[0][0].numpy()
    assert np.allclose(np.array(grid["deviation_mm"]), z, atol=1e-5)
    assert grid["x_m"][0] < grid["x_m"][-1] and grid["y_m"][0] > grid["y_m"][-1]  # x to the right, y from the top
    assert grid["x_m"][0] == pytest.approx(-0.95) and grid["y_m"][0] == pytest.approx(0.95)
    assert grid["rms_mm"] == pytest.approx(float(np.sqrt((z**2).mean())), rel=1e-4)
    assert grid["sigma_mm"] is None and grid["determined"] is False  # no covariance: nothing said of sigma


def test_sigma_is_the_covariance_through_the_b_spline():
    """One control height uncertain by 2 mm: sigma = 2 |b(x)| (largest at that control point, zero
    far from it); every control height shifting together by 3 mm (C = 9 11^T): sigma = 3 everywhere
    (the B-spline basis sums to one). Two facets with a gap: off the facets the grid is null."""
    heliostat = ideal_heliostat(cols=2, width=1.0, height=1.0, gap=0.2, control_points=C).to("cpu", torch.float64)
    heights = _heights(2)
    names = _surface_names(2)
    n = len(names)
    one = np.zeros((n, n))
    one[names.index("surface.control_heights_mm[1, 2, 2]")] [names.index("surface.control_heights_mm[1, 2, 2]")] = 4.0
    u = FitUncertainty(names, ["mm"] * n, heights.flatten().numpy(), one, 1.0, 1.0, 0.01)
    grid = surface_grid(heliostat, heights, u, 0.05)
    sigma, facet = np.array(grid["sigma_mm"], dtype=float), np.array(grid["facet"])
    assert np.isnan(sigma[facet < 0]).all() and (facet < 0).any()  # the gap between the facets
    assert np.nanmax(sigma[facet == 0]) == 0.0
    on = sigma[facet == 1]
    assert 0.3 < on.max() < 1.0 and on.min() < 1e-3  # 2 |b_i(y) b_j(x)|: each factor below 0.7 at the centre
    centre = np.unravel_index(np.nanargmax(np.where(facet == 1, sigma, np.nan)), sigma.shape)
    assert abs(grid["x_m"][centre[1]] - 0.6) < 0.06 and abs(grid["y_m"][centre[0]]) < 0.06  # facet 1's centre
    together = np.zeros((n, n))
    together[:25, :25] = 9.0  # facet 0's heights shift together by 3 mm
    u = FitUncertainty(names, ["mm"] * n, heights.flatten().numpy(), together, 1.0, 1.0, 0.01,
                       undetermined=["surface.control_heights_mm[0, 0, 0]"])
    grid = surface_grid(heliostat, heights, u, 0.05)
    sigma = np.array(grid["sigma_mm"], dtype=float)
    assert np.allclose(sigma[facet == 0], 3.0, atol=1e-6)
    assert grid["not_determined_facets"] == [0] and grid["determined"] is False


def _model_file(path, network=DrtModel, tensors=True):
    """A two-facet model file with known tracking, canting, surface and slope error and a diagonal
    covariance (sigma 0.1 mrad for tracking, 0.2 for the tilts, 0.05 for the slope error)."""
    heliostat = ideal_heliostat(cols=2, width=1.0, height=1.0, gap=0.1, control_points=C)
    config = (DrtConfig if network is DrtModel else PhysicsConfig)(effects={"sunshape": {"kind": "pillbox"}})
    model = network(config, (16, 16))
    model.heliostat = heliostat
    tracking = torch.tensor([0.5, -1.0, 0.2, 0.0, 0.3])
    canting = torch.tensor([[1.0, -0.5], [-1.0, 0.5]])  # mean zero: as the heliostat takes it
    fitted = {"tracking": tracking, "canting": canting, "surface": _heights(2).float()} if tensors else {}
    names = ([f"tracking.{p}" for p in ("axis1_offset_mrad", "axis2_offset_mrad", "pedestal_tilt_east_mrad",
                                        "pedestal_tilt_north_mrad", "non_orthogonality_mrad")]
             + [f"canting.facet_tilts_mrad[{f}, {k}]" for f in range(2) for k in range(2)]
             + ["slope_error.sigma_mrad", "sunshape.sigma_mrad"])
    sigma = np.array([0.1] * 5 + [0.2] * 4 + [0.05, 0.01])
    u = FitUncertainty(names, ["mrad"] * len(names), np.r_[tracking.numpy(), canting.flatten().numpy(), 1.2, 2.5],
                       np.diag(sigma**2), 1.5, 1.1, 0.01, undetermined=["tracking.non_orthogonality_mrad"])
    model.fitted = FitResult({"sunshape": {"kind": "gaussian", "sigma_mrad": 2.5}, "slope_error": {"sigma_mrad": 1.2}},
                             fitted, uncertainty=u)
    save_model(path, model, network.name, model.config, 1.0, {})
    return path


def test_every_fitted_value_is_written_with_its_sigma_through_the_cli(tmp_path):
    model = _model_file(tmp_path / "drt.pt")
    out, png = tmp_path / "heliostats" / "h.json", tmp_path / "heliostats" / "h.png"
    main(["fitted-heliostat", "--model", str(model), "--output", str(out), "--figure", str(png)])
    data = json.loads(out.read_text())
    assert png.read_bytes().startswith(b"\x89PNG")
    assert data["tracking_mrad"]["axis1_offset"] == {"value": 0.5, "sigma": 0.1, "determined": True}
    assert data["tracking_mrad"]["non_orthogonality"]["determined"] is False  # the fit said so
    assert data["canting_mrad"]["values"] == [[1.0, -0.5], [-1.0, 0.5]]
    assert data["canting_mrad"]["sigma"] == [[0.2, 0.2], [0.2, 0.2]]
    assert data["slope_error_mrad"] == {"value": 1.2, "sigma": 0.05, "determined": True}
    assert data["other_fitted"]["sunshape.sigma_mrad"]["value"] == 2.5
    assert data["uncertainty"]["misfit"] == 1.5
    assert len(data["surface"]["deviation_mm"]) == len(data["surface"]["y_m"])
    # the covariance holds no surface entries: no sigma, and the surface is not said to be determined
    assert data["surface"]["sigma_mm"] is None and data["surface"]["determined"] is False


def test_a_model_without_heliostat_tensors_is_refused_by_name(tmp_path):
    model = _model_file(tmp_path / "raytrace.pt", RaytraceModel, tensors=False)
    with pytest.raises(DataError, match="raytrace.pt: a raytrace model has no fitted heliostat tensors"):
        fitted_heliostat(model)
    with pytest.raises(DataError, match="grid_step_m = 0: expected a positive spacing"):
        fitted_heliostat(_model_file(tmp_path / "drt.pt"), 0)

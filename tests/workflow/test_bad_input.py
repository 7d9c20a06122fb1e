"""Bad input, as a new user gives it: each case stops with one clear line naming the key or file, or
is accepted where that is what a user means. docs/bad_input.md is the table of these cases with the
messages they really give (regenerate it with `python tests/workflow/test_bad_input.py`)."""

import copy
import math
import re
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from helioflow.config import validate_config
from helioflow.data.hdf5 import CalibrationDataset, write_dataset
from helioflow.data.paint import import_paint
from helioflow.data.surfaces import HeliostatSpec, true_heliostat, write_heliostat
from helioflow.data.synthetic import trace_dataset
from helioflow.diagnosis.ledger import update_ledger
from helioflow.errors import HelioflowError
from helioflow.io import save_torch_atomic, write_text_atomic
from helioflow.models.registry import load_model
from helioflow.workflow import (
    check_readable,
    check_results_dir,
    existing_upstream_files,
    expand_config,
    trace_params,
)

REPO = Path(__file__).resolve().parents[2]
TINY = yaml.safe_load((Path(__file__).parent / "tiny_config.yaml").read_text())
TINY_FIELD = yaml.safe_load((Path(__file__).parent / "tiny_field.yaml").read_text())
PAINT = REPO / "tests" / "data" / "paint"
DOC = REPO / "docs" / "bad_input.md"


def _config(edit: Callable[[dict], object], field: bool = False) -> dict:
    config = copy.deepcopy(TINY)
    config["networks"] = {"cgan": {"steps": 3}, "nerf": {"steps": 3}}
    if field:
        config.update(copy.deepcopy(TINY_FIELD))
    edit(config)
    return config


def _paint(**entry) -> Callable[[dict], None]:
    """An edit that adds a PAINT dataset `real` (AA39 from the sample data unless overridden)."""
    return lambda c: c["datasets"].update(real={"source": "paint", "paint_dir": str(PAINT), "heliostat": "AA39",
                                                **entry})


OWN = REPO / "examples" / "own_images"


def _own_images(images_dir: Path = OWN / "images", csv: Path = OWN / "calibration.csv", **target) -> dict:
    """An images dataset: the worked example's (examples/own_images) unless told otherwise."""
    return {"source": "images", "images_dir": str(images_dir), "csv": str(csv),
            "site": {"latitude_deg": 50.9134, "longitude_deg": 6.3868, "altitude_m": 87.0},
            "target": {"center_m": [0.0, 0.0, 20.0], "normal": [0.0, 1.0, 0.0], "width_m": 4.0, "height_m": 4.0,
                       **target},
            "heliostat": {"position_m": [0.0, 60.0, 0.0], "mount": "az_el",
                          "facets": {"rows": 1, "cols": 1, "width_m": 2.0, "height_m": 2.0}}}


def _set(path: str, value) -> Callable[[dict], None]:
    """An edit that sets the key at a dotted path."""
    *parents, key = path.split(".")

    def edit(c: dict) -> None:
        node = c
        for p in parents:
            node = node[p]
        node[key] = value

    return edit


@dataclass
class Case:
    """Bad input and the line the user sees (`expect`, a regex) or, with accepted=True, input that is
    taken as a user means it."""

    bad_input: str
    edit: Callable[[dict], object]
    expect: str
    field: bool = False


CONFIG_CASES = [
    Case("a PAINT heliostat folder named `AA39;touch PWNED;x`", _paint(heliostat="AA39;touch PWNED;x"),
         r"datasets\.real\.heliostat = 'AA39;touch PWNED;x': a name that becomes a file path"),
    Case("a heliostat `../somewhere/AA39`", _paint(heliostat="../somewhere/AA39"),
         r"datasets\.real\.heliostat = '\.\./somewhere/AA39': a name that becomes a file path"),
    Case("`experiment: ..`", _set("experiment", ".."), r"experiment = '\.\.': a name that becomes a file path"),
    Case("a dataset named `a b`", lambda c: c["datasets"].update({"a b": c["datasets"]["scan"]}),
         r"datasets: name 'a b': a name that becomes a file path"),
    Case("`networks.cgan.steps: -5`", _set("networks.cgan.steps", -5),
         r"networks\.cgan\.steps = -5: expected an integer >= 1"),
    Case("`batch_size: 0`", _set("networks.cgan.batch_size", 0),
         r"networks\.cgan\.batch_size = 0: expected an integer >= 1"),
    Case("`batch_size: -3`", _set("networks.nerf.batch_size", -3),
         r"networks\.nerf\.batch_size = -3: expected an integer >= 1"),
    Case("`checkpoint_every: 0`", _set("networks.cgan.checkpoint_every", 0),
         r"networks\.cgan\.checkpoint_every = 0: expected an integer >= 1"),
    Case("`lr: \"fast\"`", _set("networks.cgan.lr", "fast"), r"networks\.cgan\.lr = 'fast': expected a number"),
    Case("`lr: -0.01` (NeRF)", _set("networks.nerf.lr", -0.01), r"networks\.nerf\.lr = -0\.01: expected a number > 0"),
    Case("`device: cuda` on a machine without CUDA", _set("device", "cuda"),
         r"device = 'cuda', but torch sees no CUDA device on this machine"),
    Case("a `paint_dir` that does not exist", _paint(paint_dir="no/such/folder"),
         r"datasets\.real\.paint_dir = 'no/such/folder': no PAINT directory there"),
    Case("an unknown PAINT heliostat folder", _paint(heliostat="AB99"),
         r"datasets\.real\.heliostat = 'AB99': no such heliostat folder in .*; folders there: AA23, AA28"),
    Case("`sunshape: {kind: gaussian, sigma_mrad: fit}` in a variant over config.yaml's `csr: 0.1`",
         _set("model.effects.sunshape", {"kind": "gaussian", "sigma_mrad": "fit", "csr": 0.1}),
         r"model\.effects\.sunshape\.csr = 0\.1: a gaussian sun takes sigma_mrad; remove csr "
         r"\(in a --configfile variant: csr: null\)"),
    Case("a heliostat in the target plane", _set("heliostats.small.position_m", [0.0, 0.0, 0.0]),
         r"datasets\.scan: heliostat 'small' at position_m \[0\.0, 0\.0, 0\.0\] is in the target plane .* "
         r"it cannot see the target"),
    Case("a heliostat behind the target", _set("heliostats.small.position_m", [0.0, -30.0, 0.0]),
         r"datasets\.scan: heliostat 'small' at position_m \[0\.0, -30\.0, 0\.0\] is 30 m behind the target"),
    Case("`field.layout.kind: fermat` in a variant over a list layout",
         lambda c: c["field"]["layout"].update(kind="fermat", n=5, min_radius_m=20.0),
         r"field\.layout: key 'positions' is not used by kind 'fermat'; .* removes config\.yaml's keys with "
         r"positions: null", field=True),
    Case("a field heliostat behind the tower", lambda c: c["field"]["layout"]["positions"].append([0.0, -25.0, 1.0]),
         r"field: heliostat field_005 at \[0\.0, -25\.0, 1\.0\] is behind the receiver", field=True),
    Case("two field heliostats at one position", lambda c: c["field"]["layout"]["positions"].append([4.0, 24.0, 1.0]),
         r"field\.layout: heliostats field_002 \[4\.0, 24\.0, 1\.0\] and field_005 \[4\.0, 24\.0, 1\.0\] are 0\.00 m "
         r"apart, less than the mirror diagonal 1\.41 m", field=True),
    Case("`window_m: .nan`", _set("datasets.scan.window_m", math.nan),
         r"datasets\.scan\.window_m = nan: expected a finite number"),
    Case("`window_m: .inf`", _set("datasets.scan.window_m", math.inf),
         r"datasets\.scan\.window_m = inf: expected a finite number"),
    Case("`window_m: 1e-300`", _set("datasets.scan.window_m", 1e-300),
         r"datasets\.scan\.window_m = 1e-300: expected a value >= 0\.01 \(a window from 1 cm to 1 km"),
    Case("a NaN heliostat position", _set("heliostats.small.position_m", [0.0, math.nan, 0.0]),
         r"heliostats\.small\.position_m\.1 = nan: expected a finite number"),
    Case("a NaN facet width", _set("heliostats.small.facets.width_m", math.nan),
         r"heliostats\.small\.facets\.width_m = nan: expected a finite number"),
    Case("an images target `width_m: .nan`", lambda c: c["datasets"].update(own=_own_images(width_m=math.nan)),
         r"datasets\.own\.target\.width_m = nan: expected a finite number"),
    Case("`field.layout.n: 10000000`", lambda c: c["field"].update(layout={"kind": "fermat", "n": 10_000_000,
                                                                          "min_radius_m": 20.0}),
         r"field\.layout\.n = 10000000: expected a value <= 200000 \(the largest tower plants have about 170,000 "
         r"heliostats\)", field=True),
    Case("`rays: 10**12` with bilinear splatting", _set("datasets.sky.trace.rays", 10**12),
         r"datasets\.sky\.trace\.rays = 1000000000000: expected a value <= 1000000000 \(rays per image"),
    Case("`steps: 10**12`", _set("networks.cgan.steps", 10**12),
         r"networks\.cgan\.steps = 1000000000000: expected a value <= 1000000 \(a million steps is days"),
    Case("a 300-character dataset name", lambda c: c["datasets"].update({"d" * 300: c["datasets"]["scan"]}),
         r"datasets: name 'd{20}'\.\.\. \(300 characters\): expected at most 64 characters \(names become file names"),
    Case("a 300-character experiment name", _set("experiment", "e" * 300),
         r"experiment 'e{20}'\.\.\. \(300 characters\): expected at most 64 characters"),
]

ACCEPTED_CASES = [
    Case("PAINT ids typed as numbers, `holdout: [270398]`", _paint(holdout=[270398]),
         "accepted: the ids become strings ('270398')"),
    Case("`csr: null` beside `kind: gaussian` in a variant",
         _set("model.effects.sunshape", {"kind": "gaussian", "sigma_mrad": "fit", "csr": None}),
         "accepted: null removes config.yaml's key, anywhere in a variant"),
    Case("`field.layout: {kind: fermat, n: 5, min_radius_m: 20, positions: null}` in a variant",
         lambda c: c["field"]["layout"].update(kind="fermat", n=5, min_radius_m=20.0, positions=None),
         "accepted: the list layout's key is removed", field=True),
]


def _validated(case: Case) -> dict:
    return expand_config(validate_config(_config(case.edit, case.field)))


def _message(case: Case) -> str:
    with pytest.raises(HelioflowError) as info:
        _validated(case)
    return str(info.value)


needs_no_cuda = pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")


def _marks(case: Case):
    return [needs_no_cuda] if "cuda" in case.bad_input else []


@pytest.mark.parametrize("case", [pytest.param(c, id=c.bad_input, marks=_marks(c)) for c in CONFIG_CASES])
def test_bad_config_is_stopped_at_validation_with_one_line_naming_the_key(case):
    message = _message(case)
    assert re.search(case.expect, message), message
    assert "\n" not in message


def test_accepted_configs_mean_what_the_user_meant():
    holdout, csr_removed, fermat = (_validated(c) for c in ACCEPTED_CASES)
    assert holdout["datasets"]["real"]["holdout"] == ["270398"]
    assert csr_removed["model"]["effects"]["sunshape"] == {"kind": "gaussian", "sigma_mrad": "fit"}
    assert fermat["field"]["layout"] == {"kind": "fermat", "n": 5, "min_radius_m": 20.0}


# --- bad files ------------------------------------------------------------------------------------


def _dataset(images: np.ndarray) -> CalibrationDataset:
    n = len(images)
    return CalibrationDataset(images, np.linspace(-30, 30, n), np.linspace(20, 60, n), np.array(["train"] * n))


def _spot(n: int = 3) -> np.ndarray:
    yy, xx = np.mgrid[-4:4, -4:4]
    return np.repeat(np.exp(-(xx**2 + yy**2) / 4.0)[None], n, 0).astype(np.float32)


def zero_image_in_a_dataset(tmp: Path) -> None:
    images = _spot()
    images[1] = 0
    write_dataset(tmp / "datasets" / "d.h5", _dataset(images))


def saturated_image_in_a_dataset(tmp: Path) -> None:
    images = _spot()
    images[0] = 950.0
    write_dataset(tmp / "datasets" / "d.h5", _dataset(images))


def nan_image_in_a_dataset(tmp: Path) -> None:
    images = _spot()
    images[2, 3, 3] = np.nan
    write_dataset(tmp / "datasets" / "d.h5", _dataset(images))


def _paint_copy(tmp: Path, level: int) -> Path:
    """A copy of the AA39 sample folder whose first flux image is `level` in every pixel."""
    from PIL import Image  # Pillow: a dependency of matplotlib

    folder = tmp / "paint"
    shutil.copytree(PAINT, folder)
    first = sorted((folder / "AA39").glob("*-flux.png"))[0]
    shape = np.asarray(Image.open(first)).shape[:2]
    Image.fromarray(np.full(shape, level, dtype=np.uint8)).save(first)
    return folder


def black_png_in_a_paint_folder(tmp: Path) -> None:
    import_paint(_paint_copy(tmp, 0), "AA39", tmp / "d.h5", None, resolution=(32, 32))


def saturated_png_in_a_paint_folder(tmp: Path) -> None:
    import_paint(_paint_copy(tmp, 255), "AA39", tmp / "d.h5", None, resolution=(32, 32))


def spots_that_miss_the_target(tmp: Path) -> None:
    config = validate_config(_config(_set("world.effects.tracking", {"axis1_offset_mrad": 45.0})))
    spec = trace_params(config, "scan")
    spec["window_m"] = 0.5
    heliostat = tmp / "small.h5"
    write_heliostat(heliostat, true_heliostat(HeliostatSpec.from_config("small", config["heliostats"]["small"])),
                    HeliostatSpec.from_config("small", config["heliostats"]["small"]))
    trace_dataset(spec, heliostat, tmp / "scan.h5")


def garbage_model_file(tmp: Path) -> None:
    (tmp / "cgan.pt").write_bytes(b"this is not a model")
    load_model(tmp / "cgan.pt")


def corrupt_ledger(tmp: Path) -> None:
    (tmp / "ledger.json").write_text('[{"revision": 1,')
    update_ledger(tmp / "ledger.json", "d1", {}, 0.1)


def full_disk_writing_a_model(tmp: Path, monkeypatch) -> None:
    def no_space(obj, f, *args, **kwargs):
        Path(f).write_bytes(b"partial")
        raise RuntimeError("[enforce fail at inline_container.cc:626] . unexpected pos 64 vs 0")

    monkeypatch.setattr(torch, "save", no_space)
    save_torch_atomic(tmp / "models" / "cgan.pt", {"state": 1})


def full_disk_writing_a_report(tmp: Path, monkeypatch) -> None:
    def no_space(self, *args, **kwargs):
        Path.write_bytes(self, b"partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "write_text", no_space)
    write_text_atomic(tmp / "report" / "metrics.json", "{}")


def corrupt_upstream_dataset(tmp: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp)
    config = expand_config(validate_config(_config(lambda c: None)))
    write_dataset(tmp / "results/tiny/datasets/sky.h5", _dataset(_spot()))
    (tmp / "results/tiny/datasets/scan.h5").write_bytes(b"\x89HDF\r\n\x1a\n truncated")
    check_readable(existing_upstream_files(config))


def _images_folder(tmp: Path, rows: list[str]) -> dict:
    """A copy of the worked example's images (examples/own_images) with a CSV of `rows` (file,
    azimuth, elevation lines): the images dataset that reads them."""
    shutil.copytree(OWN / "images", tmp / "images", dirs_exist_ok=True)
    (tmp / "sun.csv").write_text("file,azimuth_deg,elevation_deg\n" + "\n".join(rows) + "\n")
    return _own_images(tmp / "images", tmp / "sun.csv")


def _validate_images(tmp: Path, *rows: str) -> None:
    validate_config(_config(lambda c: c["datasets"].update(own=_images_folder(tmp, list(rows)))))


def csv_row_with_an_absolute_path(tmp: Path) -> None:
    _validate_images(tmp, "cam_01.png,0,40", "/etc/hostname,10,45")


def csv_row_reaching_up_and_out(tmp: Path) -> None:
    (tmp / "elsewhere.png").write_bytes((OWN / "images" / "cam_02.png").read_bytes())
    _validate_images(tmp, "cam_01.png,0,40", "../elsewhere.png,10,45")


def csv_row_naming_a_link_to_elsewhere(tmp: Path) -> None:
    (tmp / "elsewhere.png").write_bytes((OWN / "images" / "cam_02.png").read_bytes())
    images = _images_folder(tmp, ["cam_01.png,0,40", "link.png,10,45"])
    (tmp / "images" / "link.png").symlink_to(tmp / "elsewhere.png")
    validate_config(_config(lambda c: c["datasets"].update(own=images)))


def one_file_on_two_rows(tmp: Path) -> None:
    (tmp / "images" / "sub").mkdir(parents=True)
    _validate_images(tmp, "cam_01.png,0,40", "cam_02.png,5,42", "sub/../cam_01.png,10,45")


def _import_one_png(tmp: Path, pixels: np.ndarray, mode: str) -> None:
    from PIL import Image

    from helioflow.data.images import import_images

    images = _images_folder(tmp, ["cam_01.png,0,40", "odd.png,10,45"])
    Image.fromarray(pixels, mode).save(tmp / "images" / "odd.png")
    import_images({"dataset": "own", "heliostat": "own", "images_dir": images["images_dir"], "csv": images["csv"],
                   "resolution": [16, 16], "target": images["target"], "site": None,
                   "heliostat_geometry": images["heliostat"], "splits": None, "holdout": [], "seed": 0,
                   "dni_w_m2": 1000.0}, tmp / "own.h5")


def spot_only_in_the_alpha_channel(tmp: Path) -> None:
    rgba = np.zeros((32, 32, 4), np.uint8)
    rgba[..., 3] = (255 * np.exp(-((np.mgrid[:32, :32] - 16.0) ** 2).sum(0) / 20)).astype(np.uint8)
    _import_one_png(tmp, rgba, "RGBA")


def sixteen_bit_colour_png(tmp: Path) -> None:
    """A 48-bit RGB PNG, written by hand: Pillow writes no 16-bit colour."""
    import struct
    import zlib

    spot = np.zeros((32, 32, 3), ">u2")
    spot[12:20, 12:20] = 40000
    raw = b"".join(b"\x00" + row.tobytes() for row in spot)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    images = _images_folder(tmp, ["cam_01.png,0,40", "odd.png,10,45"])
    (tmp / "images" / "odd.png").write_bytes(b"\x89PNG\r\n\x1a\n"
                                            + chunk(b"IHDR", struct.pack(">IIBBBBB", 32, 32, 16, 2, 0, 0, 0))
                                            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    from helioflow.data.images import read_rows
    from helioflow.data.paint import read_grey_png

    row = read_rows(images["csv"], images["images_dir"])[0][1]
    read_grey_png(row.path, f"{images['csv']} line {row.line} (image {row.id})", "")


def results_path_is_a_file(tmp: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp)
    (tmp / "results").mkdir()
    (tmp / "results" / "tiny").write_text("notes")
    check_results_dir(expand_config(validate_config(_config(lambda c: None))))


FILE_CASES = [
    Case("a dataset corrupted after the models were trained from it, when snakemake starts", corrupt_upstream_dataset,
         r"^results/tiny/datasets/scan\.h5 is corrupt \(.*\); everything made from it would be rerun and deleted "
         r"first: delete the file to rebuild it, or restore it"),
    Case("an all-zero image in a dataset", zero_image_in_a_dataset,
         r"d\.h5: image 1 \(split train, sun azimuth 0\.00 deg, elevation 40\.00 deg\) is all zero: it shows no focal "
         r"spot \(1 such image\(s\), indices \[1\]\)"),
    Case("an image with the same flux in every pixel (saturated) in a dataset", saturated_image_in_a_dataset,
         r"d\.h5: image 0 \(split train, sun azimuth -30\.00 deg, elevation 20\.00 deg\) is 950 W/m\^2 in every pixel "
         r"\(saturated\?\): it shows no focal spot \(1 such image\(s\), indices \[0\]\)"),
    Case("a NaN pixel in a dataset", nan_image_in_a_dataset,
         r"d\.h5: image 2 \(split train, sun azimuth 30\.00 deg, elevation 60\.00 deg\) holds NaN or infinite flux"),
    Case("an all-black PNG in a PAINT folder", black_png_in_a_paint_folder,
         r"AA39/\d+-flux\.png: the image is black \(all zero\): it shows no focal spot"),
    Case("a saturated PNG (255 everywhere) in a PAINT folder", saturated_png_in_a_paint_folder,
         r"AA39/\d+-flux\.png: the image is grey level 255 in every pixel \(saturated\?\)"),
    Case("spots that miss the target (a 45 mrad tracking error, a 0.5 m window)", spots_that_miss_the_target,
         r"dataset 'scan': the spot misses the target window in \d of 6 images \(first: sun azimuth 10\.00 deg"),
    Case("a garbage `.pt` model file", garbage_model_file,
         r"cgan\.pt is not a helioflow model file \(truncated or corrupt\?\)"),
    Case("a corrupt ledger JSON", corrupt_ledger,
         r"ledger\.json: not a readable ledger \(JSON list of model revisions\): .*; repair it or delete it"),
    Case("a full disk while saving a model", full_disk_writing_a_model,
         r"cannot write .*models/cgan\.pt: the write failed \(is the disk full\?\): \[enforce fail"),
    Case("a full disk while writing a JSON output", full_disk_writing_a_report,
         r"cannot write .*report/metrics\.json: No space left on device"),
    Case("a CSV row whose file is an absolute path (`/etc/hostname`)", csv_row_with_an_absolute_path,
         r"config: datasets\.own\.csv: .*sun\.csv line 3: file '/etc/hostname' is /etc/hostname, outside images_dir "
         r".*/images; every image must lie inside images_dir \(after resolving '\.\.' and links\)"),
    Case("a CSV row `../elsewhere.png`", csv_row_reaching_up_and_out,
         r"sun\.csv line 3: file '\.\./elsewhere\.png' is .*/elsewhere\.png, outside images_dir"),
    Case("a CSV row naming a link to a PNG elsewhere", csv_row_naming_a_link_to_elsewhere,
         r"sun\.csv line 3: file 'link\.png' is .*/elsewhere\.png, outside images_dir"),
    Case("one image on two CSV rows (`cam_01.png`, `sub/../cam_01.png`: two ids)", one_file_on_two_rows,
         r"sun\.csv lines 2 and 4 both name the image .*/images/cam_01\.png; each image is one measurement at one "
         r"sun position: remove one of the lines"),
    Case("an RGBA PNG whose spot is only in the alpha channel", spot_only_in_the_alpha_channel,
         r"sun\.csv line 3 \(image odd\): .*odd\.png has transparent pixels \(\d+\.\d% of them; alpha channel\): "
         r"helioflow reads the grey level, not the alpha"),
    Case("a 16-bit RGB PNG", sixteen_bit_colour_png,
         r"sun\.csv line 3 \(image odd\): .*odd\.png is a 16-bit RGB PNG, which helioflow cannot read at 16 bits"),
    Case("`results/<experiment>` is a regular file", results_path_is_a_file,
         r"^results/tiny is a file, not a folder: the outputs of experiment 'tiny' go under results/tiny/; move the "
         r"file away or choose another experiment name"),
]


def _file_message(case: Case, tmp: Path, monkeypatch) -> str:
    run = case.edit
    with pytest.raises(HelioflowError) as info:
        run(tmp, monkeypatch) if "monkeypatch" in run.__code__.co_varnames else run(tmp)
    return str(info.value)


@pytest.mark.parametrize("case", [pytest.param(c, id=c.bad_input) for c in FILE_CASES])
def test_bad_file_gives_one_line_naming_it_and_leaves_nothing_half_written(case, tmp_path, monkeypatch):
    message = _file_message(case, tmp_path, monkeypatch)
    assert re.search(case.expect, message), message
    assert "\n" not in message
    assert not [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp")], "a temporary file was left"
    if "full disk" in case.bad_input:
        assert not [p for p in tmp_path.rglob("*") if p.is_file()], "a half-written output was left"


TWICE = "networks:\n  nearest: {}\nexperiment: twice\nnetworks:\n  drt: {}\n"  # a variant with a key twice
TWICE_MESSAGE = "helioflow: variant.yaml: the key 'networks' appears twice in one mapping (lines 1 and 4): keep one"
# a variant of nested aliases ("billion laughs"): a list of nine, then nine of the level below, eight times
LAUGHS = "a0: &a0 [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]\n" for i in range(1, 9))
LAUGHS_MESSAGE = ("helioflow: variant.yaml: its aliases expand to 490,329,036 nodes beyond the 28 written, more than "
                  "the bound 100,000; write the values out")

# --- the table in docs/bad_input.md ---------------------------------------------------------------


def _shown(message: str, tmp: Path | None = None) -> str:
    """A message as the table shows it: temporary and repository folders as `…/`."""
    for folder in filter(None, (str(tmp) + "/" if tmp else None, str(PAINT) + "/", str(REPO) + "/")):
        message = message.replace(folder, "…/")
    return message.replace("|", "\\|")


def table(tmp: Path, monkeypatch) -> str:
    """docs/bad_input.md: every case above with the message it gives now."""
    rows = [f"| {c.bad_input} | `helioflow: {_shown(_message(c))}` |" for c in CONFIG_CASES]
    rows += [f"| {c.bad_input} | {c.expect} |" for c in ACCEPTED_CASES]
    rows.append(f"| a key given twice in a `--configfile` variant (two `networks:` blocks) | `{TWICE_MESSAGE}` |")
    rows.append(f"| a `--configfile` variant of nested aliases (a \"billion laughs\", 9^9 values from under 500 bytes) "
                f"| `{LAUGHS_MESSAGE}` |")
    for i, c in enumerate(FILE_CASES):
        with monkeypatch.context() as m:
            folder = tmp / f"case{i}"
            folder.mkdir()
            rows.append(f"| {c.bad_input} | `{_shown(_file_message(c, folder, m), folder)}` |")
    return "\n".join([
        "# Bad input and what you see",
        "",
        "Generated by `python tests/workflow/test_bad_input.py` from the cases of that test module, which",
        "checks that every message below is what helioflow prints now. Config errors stop `snakemake` (also",
        "`snakemake -n`) before any job runs, with the one line shown. File errors stop the rule that reads or",
        "writes the file, with the line `helioflow <step>: error: <message>` in its log, and leave no output",
        "that looks complete and no temporary file.",
        "",
        "| bad input | what you see |",
        "|---|---|",
        *rows,
        "",
    ])


@pytest.mark.skipif(torch.cuda.is_available(), reason="the table is written on a machine without CUDA")
def test_the_docs_table_shows_the_messages_given_now(tmp_path, monkeypatch):
    assert DOC.read_text() == table(tmp_path, monkeypatch), (
        "docs/bad_input.md is out of date: regenerate it with `python tests/workflow/test_bad_input.py`")


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as tmp, pytest.MonkeyPatch.context() as mp:
        DOC.write_text(table(Path(tmp), mp))
    print(f"wrote {DOC}", file=sys.stderr)
    sys.exit(0)  # the snakemake cases below need the tests' support package, which a script does not see


# --- through snakemake ----------------------------------------------------------------------------

from support.pipeline import _workdir, snakemake  # noqa: E402  (the pipeline tests' runner)


@pytest.mark.parametrize("case", [pytest.param(c, id=c.bad_input, marks=_marks(c)) for c in CONFIG_CASES])
def test_snakemake_dry_run_stops_with_the_one_line(case, tmp_path):
    workdir = _workdir(tmp_path / "run", _config(case.edit, case.field))
    peak = tmp_path / "peak_kb"
    proc = snakemake(workdir, "-n", "all", peak_rss=peak)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode != 0
    assert lines == [f"helioflow: {_message(case)}"], proc.stderr
    assert not (workdir / "results").exists() and not (workdir / "PWNED").exists()
    assert int(peak.read_text()) < 500 * 1024, f"snakemake -n peaked at {int(peak.read_text()) // 1024} MB"


def test_a_key_given_twice_in_a_variant_stops_snakemake_with_one_line(tmp_path):
    """YAML keeps the last of a key given twice, so a variant with two `networks:` blocks would run with
    the second alone: every config file snakemake read is read again strictly."""
    workdir = _workdir(tmp_path / "run", _config(lambda c: None))
    (workdir / "variant.yaml").write_text(TWICE)
    proc = snakemake(workdir, "-n", "all", "--configfile", "variant.yaml")
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode != 0
    assert lines == [TWICE_MESSAGE], proc.stderr
    assert not (workdir / "results").exists()


def test_a_variant_of_nested_aliases_stops_snakemake_at_once_with_one_line(tmp_path):
    """Nested aliases written out are 9^9 values, which the config's checks would walk for minutes:
    their count, from the YAML before it is built, stops the run (snakemake itself keeps lists as they
    are; a baseline `snakemake -n` takes about 4 s)."""
    workdir = _workdir(tmp_path / "run", _config(lambda c: None))
    (workdir / "variant.yaml").write_text(LAUGHS)
    peak = tmp_path / "peak_kb"
    start = time.monotonic()
    proc = snakemake(workdir, "-n", "all", "--configfile", "variant.yaml", timeout=60, peak_rss=peak)
    seconds = time.monotonic() - start
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode != 0
    assert lines == [LAUGHS_MESSAGE], proc.stderr
    assert seconds < 10, f"snakemake -n took {seconds:.1f} s"
    assert int(peak.read_text()) < 500 * 1024, f"snakemake -n peaked at {int(peak.read_text()) // 1024} MB"
    assert not (workdir / "results").exists()


def test_a_results_path_that_is_a_file_stops_snakemake_with_one_line(tmp_path):
    workdir = _workdir(tmp_path / "run", _config(lambda c: None))
    (workdir / "results").write_text("notes")
    proc = snakemake(workdir, "-n", "all")
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode != 0 and lines == [
        "helioflow: results is a file, not a folder: the outputs of experiment 'tiny' go under results/tiny/; move the "
        "file away or choose another experiment name"], proc.stderr


def test_a_corrupt_dataset_stops_snakemake_before_it_deletes_the_models_made_from_it(tmp_path):
    workdir = _workdir(tmp_path / "run", _config(lambda c: None))
    model = workdir / "results/tiny/models/scan/cgan.pt"
    model.parent.mkdir(parents=True)
    save_torch_atomic(model, {"state": 1})
    dataset = workdir / "results/tiny/datasets/scan.h5"
    dataset.parent.mkdir(parents=True)
    dataset.write_bytes(b"\x89HDF\r\n\x1a\n truncated")
    proc = snakemake(workdir, "-j1", "all")
    assert proc.returncode != 0
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("helioflow: results/tiny/datasets/scan.h5 is corrupt ("), lines
    assert lines[0].endswith("delete the file to rebuild it, or restore it")
    assert model.is_file()


def test_a_shell_word_in_a_requested_path_runs_nothing(tmp_path):
    """`snakemake "results/<exp>/surfaces/AA39;touch PWNED;x.h5"`: no rule makes that name."""
    config = _config(_paint())
    workdir = _workdir(tmp_path / "run", config)
    for target in ("results/tiny/surfaces/AA39;touch PWNED;x.h5", "results/tiny/datasets/x;touch PWNED;x.h5"):
        proc = snakemake(workdir, "-j1", target)
        assert proc.returncode != 0 and "MissingRuleException" in proc.stderr, proc.stderr
    assert not (workdir / "PWNED").exists() and not (workdir / "results").exists()


def test_every_shell_command_quotes_its_paths():
    """Every {input}, {output}, {log} and {params} placeholder in a rule's shell command is quoted
    (`:q`), so that no file name or parameter is read as shell syntax."""
    unquoted = []
    for smk in sorted((REPO / "workflow" / "rules").glob("*.smk")):
        shell = re.findall(r'shell:\n((?:\s+".*"\n)+)', smk.read_text())
        assert shell or "shell:" not in smk.read_text(), smk
        for command in shell:
            unquoted += [f"{smk.name}: {{{p}}}" for p in re.findall(r"\{([^{}:]+)\}", command)]
    assert unquoted == []


SAME_RESULTS = ["results/tiny/models/scan/cgan.pt", "results/tiny/models/scan/nerf.pt",
                "results/tiny/metrics/scan/cgan.json", "results/tiny/metrics/scan/nerf.json",
                "results/tiny/metrics/scan/cgan.csv"]


@pytest.mark.slow
def test_one_job_at_a_time_and_two_at_once_give_the_same_files(tmp_path):
    """-j1 and -j2 on the same config: bit-identical model files and metrics (each job computes with
    torch_threads threads, whatever -j)."""
    config = _config(lambda c: c["networks"].update(cgan={"steps": 8, "batch_size": 4, "features": 4, "latent": 8},
                                                    nerf={"steps": 8, "batch_size": 2, "rays": 64, "width": 16}))
    outputs = {}
    for jobs in ("1", "2"):
        workdir = _workdir(tmp_path / f"j{jobs}", config)
        proc = snakemake(workdir, f"-j{jobs}", *SAME_RESULTS)
        assert proc.returncode == 0, proc.stderr[-3000:]
        outputs[jobs] = {p: (workdir / p).read_bytes() for p in SAME_RESULTS}
    for path in SAME_RESULTS:
        assert outputs["1"][path] == outputs["2"][path], path

"""The README's first run, as a new user runs it: `snakemake -j2 all --configfile
workflow/variants/hidden_effect_demo.yaml` end to end, and the walkthrough's quotes of its verdict
are what it prints."""

import json
import re
import shutil

import pytest
from support.pipeline import REPO, _workdir, snakemake

FIRST_RUN = "snakemake -j2 all --configfile workflow/variants/hidden_effect_demo.yaml"
RESULTS = "results/hidden_effect_demo"


def readme_quote() -> str:
    """The verdict quoted in the README's walkthrough, step 1 (between *" and "*), on one line."""
    walkthrough = (REPO / "README.md").read_text().split("## The diagnosis loop", 1)[1]
    quote = re.search(r'\*"(.+?)"\*', walkthrough, re.DOTALL)
    assert quote, "the README's diagnosis loop quotes no verdict"
    return " ".join(quote.group(1).split())


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    """The first run in a fresh folder beside the repository's Snakefile, workflow and config."""
    assert FIRST_RUN in (REPO / "README.md").read_text()  # the command tested is the README's
    workdir = _workdir(tmp_path_factory.mktemp("first_run"))
    shutil.copy(REPO / "config.yaml", workdir / "config.yaml")
    proc = snakemake(workdir, *FIRST_RUN.split()[1:], timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return workdir, proc


@pytest.mark.slow
def test_the_first_run_finishes_with_its_report_and_a_verdict(first_run):
    workdir, proc = first_run
    assert "helioflow: config.yaml's plan falls away: this experiment has no drt network" in proc.stderr
    assert (workdir / RESULTS / "report.html").is_file()
    diagnosis = json.loads((workdir / RESULTS / "diagnosis" / "sanity_check.json").read_text())
    named = [r["changes"] for r in diagnosis["ranking"] if r["meaningful"]]
    assert named == ["surface", "tracking"], diagnosis["verdict"]  # the world's hidden surface and tracking
    assert "implausible" not in diagnosis["verdict"]
    # the joint fit's surface is near the world's (0.44 mm RMS of control heights), not the 3 mm of a
    # surface fitted alone to a spot that the tracking error moved
    surface = diagnosis["final_fitted"]["surface.control_heights_mm_rms"]
    assert 0.2 < surface < 0.8, diagnosis["final_fitted"]
    walkthrough = " ".join((REPO / "docs" / "diagnosis.md").read_text().split())
    quoted = re.search(r"fitted beside tracking it is ([0-9.]+) mm RMS", walkthrough)
    assert quoted and float(quoted.group(1)) == round(surface, 2), (quoted, surface)  # as docs/diagnosis.md says
    # ... and as it says of how well the images determine it
    sigma = diagnosis["uncertainty"]["tensors"]["surface.control_heights_mm"]
    assert sigma["undetermined"] == 36 and "marks all of them not determined" in walkthrough


@pytest.mark.slow
def test_the_readme_quotes_the_verdict_the_first_run_prints(first_run):
    workdir, _ = first_run
    printed = json.loads((workdir / RESULTS / "diagnosis" / "sanity_check.json").read_text())["verdict"]
    for fragment in readme_quote().split("…"):
        assert fragment.strip() in printed, f"the README quotes {fragment.strip()!r}; the run prints: {printed}"

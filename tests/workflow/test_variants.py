"""Every shipped variant, and every stack of config files the README and the docs give a command for:
validated over config.yaml as snakemake layers them, and dry-run by snakemake itself (`snakemake -n all`).
A new variant that snakemake refuses fails here, not in a user's first run."""

import re
from pathlib import Path

import pytest
import yaml
from snakemake.utils import update_config
from support.pipeline import REPO, layered

from helioflow.config import follow_variant
from helioflow.errors import ConfigError

VARIANTS = REPO / "workflow" / "variants"
DOCUMENTS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")), *sorted(VARIANTS.glob("*.yaml"))]
# config files the docs name as the user's own (their content is the user's): not shipped
USERS_OWN = {"my_variant.yaml", "plant_user.yaml", "throughput.yaml"}
# a command's `--configfile` and the file names after it, over line breaks, `\` and a YAML comment's `#`
CONFIGFILES = re.compile(r"--configfile((?:[\s\\#]+[\w./-]+\.yaml)+)")


def documented_stacks() -> set[tuple[str, ...]]:
    """Every list of config files a `snakemake ... --configfile a.yaml b.yaml` command in the README,
    docs/*.md or a variant's comments gives, as paths from the repository root."""
    stacks = set()
    for document in DOCUMENTS:
        for match in CONFIGFILES.finditer(document.read_text()):
            stacks.add(tuple(re.findall(r"[\w./-]+\.yaml", match.group(1))))
    return stacks


def shipped_stacks() -> list[tuple[str, ...]]:
    """Each shipped variant alone, and every documented stack of shipped files (a stack naming a
    user's own file is left out: the docs give its content, not the file)."""
    alone = {(str(path.relative_to(REPO)),) for path in VARIANTS.glob("*.yaml")}
    documented = {s for s in documented_stacks() if not USERS_OWN & {Path(f).name for f in s}}
    return sorted(alone | documented)


def test_the_docs_name_only_shipped_variants_or_the_users_own_files():
    named = {f for stack in documented_stacks() for f in stack}
    assert {f for f in named if not (REPO / f).is_file()} <= USERS_OWN
    assert ("workflow/variants/aim.yaml", "workflow/variants/aim_drt.yaml",
            "workflow/variants/aim_margin.yaml") in documented_stacks()  # the parser reads a command over lines


@pytest.mark.parametrize("stack", shipped_stacks(), ids=lambda s: "+".join(Path(f).stem for f in s))
def test_every_shipped_variant_and_documented_stack_validates(stack):
    config = layered(stack)
    assert config["experiment"] == yaml.safe_load((REPO / stack[-1]).read_text())["experiment"]
    if config.get("plan"):
        assert "drt" in config["networks"] and set(config["plan"]["datasets"]) <= set(config["datasets"])


def test_a_variant_that_drops_the_planned_dataset_takes_the_plan_with_it():
    config = layered((), {"experiment": "no_sanity", "datasets": {"sanity_check": None}})
    assert "plan" not in config and "sanity_check" not in config["datasets"] and "semi_sphere" in config["datasets"]
    config = layered((), {"experiment": "no_drt", "networks": {"drt": None}})
    assert "plan" not in config and "sanity_check" in config["datasets"]


def test_a_plan_follows_the_datasets_that_remain_and_says_so():
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    config["plan"]["datasets"] = ["sanity_check", "semi_sphere"]  # as if config.yaml named both
    config["datasets"]["sanity_check"] = None
    notes = follow_variant(config, {"datasets": {"sanity_check": None}})
    assert config["plan"]["datasets"] == ["semi_sphere"]
    assert notes == ["config.yaml's plan.datasets follows the experiment: semi_sphere (not sanity_check)"]


def test_the_field_falls_away_with_the_network_it_names():
    user = {"experiment": "no_nearest", "networks": {"nearest": None}}
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    update_config(config, user)
    assert follow_variant(config, user) == [
        "config.yaml's field falls away: its network 'nearest' is not in this experiment's networks"]
    assert config["field"] is None
    assert "field" not in layered((), user)


def test_a_plan_or_field_the_user_wrote_is_checked_as_written():
    with pytest.raises(ConfigError, match="plan.datasets has 'sanity_check', which is not in datasets"):
        layered((), {"datasets": {"sanity_check": None}, "plan": {"datasets": ["sanity_check"]}})
    with pytest.raises(ConfigError, match="plan.datasets has 'sanity_check', but networks has no drt"):
        layered((), {"networks": {"drt": None}, "plan": {"datasets": ["sanity_check"]}})
    with pytest.raises(ConfigError, match="field.network = 'nearest' is not in networks"):
        layered((), {"networks": {"nearest": None}, "field": {"network": "nearest"}})


@pytest.fixture(scope="module")
def repository_copy(tmp_path_factory) -> Path:
    """A folder that holds what the variants read, linked from the repository (a dry run there
    writes only snakemake's own .snakemake/ metadata)."""
    folder = tmp_path_factory.mktemp("variants")
    for name in ("Snakefile", "workflow", "config.yaml", "examples", "tests"):
        (folder / name).symlink_to(REPO / name)
    (folder / "no_sanity_check.yaml").write_text("experiment: no_sanity_check\ndatasets: {sanity_check: null}\n")
    return folder


def dry_run(folder: Path, configfiles: tuple[str, ...]) -> None:
    """`snakemake -n all --configfile <configfiles>` in `folder`, in this process through snakemake's
    API (0.3-1 s a stack after the first, against 8 s for a new process that imports torch again);
    what it prints goes to the captured stdout and stderr."""
    from snakemake.api import SnakemakeApi
    from snakemake.settings.types import ConfigSettings, DAGSettings, OutputSettings, ResourceSettings

    with SnakemakeApi(OutputSettings(dryrun=True)) as api:
        workflow = api.workflow(resource_settings=ResourceSettings(cores=1), snakefile=folder / "Snakefile",
                                config_settings=ConfigSettings(configfiles=[folder / f for f in configfiles]),
                                workdir=folder)
        workflow.dag(DAGSettings(targets={"all"})).execute_workflow(executor="dryrun")


@pytest.mark.parametrize("stack", [(), *shipped_stacks(), ("no_sanity_check.yaml",)],
                         ids=lambda s: "+".join(Path(f).stem for f in s) or "default")
def test_snakemake_dry_runs_every_shipped_variant_and_documented_stack(repository_copy, stack, capfd,
                                                                        monkeypatch):
    """`snakemake -n all --configfile <stack>` (config.yaml alone for the empty stack) is accepted and
    schedules the stack's experiment's report (a variant that drops sanity_check and sets nothing else
    among them: config.yaml's plan follows)."""
    monkeypatch.chdir(repository_copy)
    dry_run(repository_copy, stack)
    out, err = capfd.readouterr()
    experiment = yaml.safe_load((repository_copy / (stack or ("config.yaml",))[-1]).read_text())["experiment"]
    assert f"results/{experiment}/report.html" in out + err, (out + err)[-3000:]
    if stack == ("no_sanity_check.yaml",):
        assert "helioflow: config.yaml's plan falls away: this experiment has none of its datasets" in err

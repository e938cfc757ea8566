# lagsplat pipeline. Each rule calls one CLI stage:
#   python -m lagsplat <stage> system=<name> [hydra overrides]
#
#   snakemake -c2 toy                              # the embedded default clip, end to end
#   snakemake -c2 results/tables/physical.tex      # paper Table 2 rows for all systems
#   snakemake -c2 results/tables/physical.tex --config raw_dir=/path/to/clips
#   snakemake -c2 toy --config overrides="stage1.steps=200"
#   snakemake -c2 results/tables/two_carts_inertia.tex   # inertia ablation on one frozen chart
#
#   snakemake -c2 results/tables/krauss.tex --config krauss_source=synthetic   # soft-robot benchmark, offline surrogate
#   snakemake -c2 paper                            # every table and figure of the paper -> docs/results.md (workflow/rules/paper.smk)
#
# Multi-run targets, one job per run (workflow/rules/suite.smk, seeds.smk):
#   snakemake -c8 suite                            # blind diagnosis suite: one job per clip, then the scoring
#   snakemake -c8 results/tables/toy_seeds.md      # toy trained with each seed of conf/config.yaml seed_table.seeds
#   snakemake --profile profiles/slurm suite       # the same jobs submitted to SLURM (profiles/slurm/config.yaml)
#   snakemake --profile profiles/local -c16 seeds  # a big box (profiles/local/config.yaml)
# Every job writes its output (stdout and stderr) to results/logs/...; a failed job's log is
# printed with --show-failed-logs (set in both profiles).
#
# Config keys (--config k=v): raw_dir (where source clips are kept / downloaded),
# overrides (extra Hydra overrides for every stage), results_dir; soft-robot
# benchmark: krauss_source (zenodo | synthetic), krauss_archive (local
# processed_data.zip), see workflow/rules/krauss.smk; blind diagnosis suite:
# suite_budget, suite_n_per_effect, suite_args (workflow/rules/suite.smk); seeds:
# seeds, seed_systems (workflow/rules/seeds.smk).
import json

import yaml
from pathlib import Path

from snakemake.utils import validate

from lagsplat.artifacts import Artifacts
from lagsplat.cli_common import seeded_variants

# a bad --config key or value stops here, before any job, naming it (workflow/schemas/config.schema.yaml)
validate(config, "workflow/schemas/config.schema.yaml")

RAW = config.get("raw_dir", "data/raw")
RESULTS = config.get("results_dir", "results")
OVR = config.get("overrides", "")
TABLES = {
    "physical": ["toy", "oscillating_cart", "red_apple_pendulum"],
    "smoke": ["toy_tiny"],
}


def _csv(value):
    """``--config`` value -> list of strings: ``"0,1,2"``, a single number, or a YAML list."""
    items = value if isinstance(value, (list, tuple)) else str(value).split(",")
    return [str(v).strip() for v in items if str(v).strip()]


_CONF = yaml.safe_load(Path("conf/config.yaml").read_text())
# ablation name -> variants compared on one frozen chart (conf/config.yaml `ablations`)
ABLATIONS = _CONF["ablations"]
# --config ablation_seeds=0,1,2,3,4: each variant's Stage 2 once per seed (<variant>@seed<k>), rows the medians
_ablation_seeds = config.get("ablation_seeds", _CONF["ablation_seeds"])
ABLATION_SEEDS = None if _ablation_seeds is None else [int(k) for k in _csv(_ablation_seeds)]


def system_conf(name):
    """The system's YAML (conf/system/<name>.yaml), read once for file names and URLs."""
    path = Path("conf/system") / f"{name}.yaml"
    if not path.exists():
        raise ValueError(f"unknown system {name!r}: {path} does not exist")
    return yaml.safe_load(path.read_text())["system"]


def source_entries(s):
    """The source mapping(s) of a system block: ``source``, or every entry of ``sources`` (multi-clip)."""
    return list(s.get("sources") or []) or [s.get("source", {})]


def raw_input(name):
    """Source file(s) of a system, or nothing for procedural (synth) systems."""
    return [f"{RAW}/{e['file']}" for e in source_entries(system_conf(name)) if "file" in e]


# downloadable source file -> system that describes it
RAW_FILES = {}
for _p in sorted(Path("conf/system").glob("*.yaml")):
    for _e in source_entries(yaml.safe_load(_p.read_text())["system"]):
        if "file" in _e:
            RAW_FILES[_e["file"]] = _p.stem


# Artifact paths as Snakemake patterns, from the one module that names them (lagsplat.artifacts):
# ART.clip == "results/{system}/clip.npz", VAR.stage2 == "results/{system}/variants/{variant}/stage2.pt".
ART = Artifacts.at(f"{RESULTS}/{{system}}")
VAR = Artifacts.at(f"{RESULTS}/{{system}}", f"{RESULTS}/{{system}}/variants/{{variant}}")


ARTIFACT_NAMES = set(Artifacts.names())


def cli(stage, inputs=(), outputs=(), extra="", system="{wildcards.system}", lists=()):
    """The shell command of a rule that runs one CLI stage: the stage reads exactly the rule's named ``{input}`` and
    writes its ``{output}`` (``artifacts.<name>=PATH``), and writes its own log (``log={log}``) while its output also
    reaches the screen (Stage 1 and Stage 2 print a progress line every ~30 s).

    ``inputs="params"``: the named inputs ``params.inputs`` hands (:func:`named_inputs`), for a rule whose inputs
    depend on the system; ``lists``: list-valued artifacts (``'artifacts.<name>=[...]'`` from ``params.<name>``,
    :func:`joined`); ``system=None``: a stage that reads no system of its own (a table over several)."""
    handed = ["{params.inputs}"] if inputs == "params" else [f"artifacts.{n}={{input.{n}}}" for n in inputs]
    handed += [f"'artifacts.{n}=[{{params.{n}}}]'" for n in lists] + [f"artifacts.{n}={{output.{n}}}" for n in outputs]
    return (
        f"python -m lagsplat {stage} " + (f"system={system} " if system else "") + f"raw_dir={RAW} results_dir={RESULTS} threads={{threads}} "
        + " ".join(handed) + f" log={{log}} {extra} {OVR}"
    )


def named_inputs(wildcards, input):
    """``artifacts.<name>=PATH`` for each named input of the job that is an artifact (``params.inputs`` of a rule
    whose inputs depend on the system: a stop record or a folder of source files is not handed)."""
    return " ".join(f"artifacts.{k}={v}" for k, v in input.items() if k in ARTIFACT_NAMES)


def joined(name):
    """A params function: the paths of the named input ``name``, comma-separated (a list-valued artifact of :func:`cli`)."""
    return lambda wildcards, input: ",".join(input[name])


def ingest_input(name):
    """The source file ingest reads, named ``source`` (handed as ``artifacts.source``) for a system with one
    ``source`` file; a multi-clip system's files (``sources``) are read from its configuration; none for a
    procedural (synth) system."""
    files = raw_input(name)
    return {"source": files[0]} if len(files) == 1 and not system_conf(name).get("sources") else {"sources": files}


# A system is one folder name (conf/system/<name>.yaml): never a path, so results/<a>/<b>/metrics.json
# (a seed's tree, results/seeds/seed<k>/<system>/) is not mistaken for system "<a>/<b>".
wildcard_constraints:
    system="[A-Za-z0-9_]+",


include: "workflow/rules/ingest.smk"
include: "workflow/rules/views.smk"
include: "workflow/rules/stage1.smk"
include: "workflow/rules/chart.smk"
include: "workflow/rules/stage2.smk"
include: "workflow/rules/evaluate.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/krauss.smk"
include: "workflow/rules/diagnose.smk"
include: "workflow/rules/suite.smk"
include: "workflow/rules/seeds.smk"
include: "workflow/rules/realistic.smk"
include: "workflow/rules/paper.smk"


# Snakemake keeps one onstart handler: before the first job, the projected wall time of the paper target item by
# item (workflow/rules/paper.smk), else of the soft-robot jobs (workflow/rules/krauss.smk).
onstart:
    for _projection in (_paper_projection, _krauss_projection):
        try:
            if _projection():
                break
        except Exception as e:  # a projection is a courtesy: it never stops a run
            print(f"[lagsplat] no projected wall time ({type(e).__name__}: {e})", flush=True)


rule toy:
    """The main job on the embedded default clip."""
    input:
        f"{RESULTS}/toy/metrics.json",
        f"{RESULTS}/toy/figures/rollout.png",

# Blind diagnosis suite (benchmarks/diagnosis.py) as one job per clip, then one scoring job.
#
#   snakemake -c8 suite                                        # every clip of the suite, budget cheap
#   snakemake -c8 results/benchmarks/diagnosis_standard.md     # another budget (cheap | standard | full)
#   snakemake --profile profiles/slurm suite                   # one SLURM job per clip
#
# Config keys (--config k=v):
#   suite_budget        budget of the `suite` target (default cheap; BUDGETS in benchmarks/diagnosis.py)
#   suite_n_per_effect  clips per (system, effect), as --n-per-effect (default 2)
#   suite_args          extra flags for every per-clip job, e.g. "--dof-refit --refit-epochs 150"
#                       (a change reruns the clips: Snakemake's params trigger)
# Per clip, the pipeline's artifacts stay cached under results/diagnosis_bench/<budget>/<clip>/
# (the script's own cache: a failed or cancelled job resumes where it stopped); the scored row is
# results/benchmarks/diagnosis/<budget>/<clip>.json, the summary (per-clip table, confusion matrix,
# accuracy, gap reductions) results/benchmarks/diagnosis_<budget>.md and .json.
import re

from lagsplat.synth.effect_clips import blind_suite

SUITE_BUDGET = str(config.get("suite_budget", "cheap"))
SUITE_N = int(config.get("suite_n_per_effect", 2))
SUITE_ARGS = str(config.get("suite_args", ""))
SUITE_CLIPS = [e["name"] for e in blind_suite(SUITE_N)]
SUITE_CACHE = f"{RESULTS}/diagnosis_bench"
SUITE_ROWS = f"{RESULTS}/benchmarks/diagnosis"


rule suite_clip:
    """One clip of the blind suite through ingest -> Stage 1 -> chart -> Stage 2 -> evaluate -> diagnose
    (benchmarks/diagnosis.py --clip), written as its scored row."""
    output:
        f"{SUITE_ROWS}/{{budget}}/{{clip}}.json",
    log:
        f"{RESULTS}/logs/diagnosis_bench/{{budget}}/{{clip}}.log",
    wildcard_constraints:
        budget="[A-Za-z0-9]+",
        clip="|".join(re.escape(c) for c in SUITE_CLIPS),
    params:
        extra=SUITE_ARGS,
    threads: 1  # the budgets are tuned on one core; more: --set-threads suite_clip=2
    resources:
        mem_mb=4000,
        # minutes, with a wide margin over the stage wall times the rows record (results/benchmarks/diagnosis_cheap.md)
        runtime=lambda w: 30 if w.budget == "cheap" else 180,
    shell:
        f"NUMBA_NUM_THREADS={{threads}} python benchmarks/diagnosis.py --clip {{wildcards.clip}} --budget {{wildcards.budget}} "
        f"--n-per-effect {SUITE_N} --results {SUITE_CACHE} --threads {{threads}} --row {{output}} {{params.extra}} > {{log}} 2>&1"


rule suite_summary:
    """Score the suite from the per-clip rows (benchmarks/diagnosis.py --gather): markdown summary and JSON record."""
    input:
        lambda w: [f"{SUITE_ROWS}/{w.budget}/{c}.json" for c in SUITE_CLIPS],
    output:
        md=f"{RESULTS}/benchmarks/diagnosis_{{budget}}.md",
        json=f"{RESULTS}/benchmarks/diagnosis_{{budget}}.json",
    log:
        f"{RESULTS}/logs/benchmarks/diagnosis_{{budget}}.log",
    wildcard_constraints:
        budget="[A-Za-z0-9]+",
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    shell:
        "python benchmarks/diagnosis.py --gather {input} --markdown {output.md} --json {output.json} > {log} 2>&1"


rule suite:
    """The blind diagnosis suite at --config suite_budget (default cheap)."""
    input:
        f"{RESULTS}/benchmarks/diagnosis_{SUITE_BUDGET}.md",


localrules:
    suite_summary,

# One system trained with several seeds: one job per (system, seed), then one table per system.
#
#   snakemake -c8 results/tables/toy_seeds.md                 # toy, seeds of conf/config.yaml seed_table.seeds
#   snakemake -c8 seeds --config seeds=0,1,2,3,4 seed_systems=toy,oscillating_cart
#   snakemake --profile profiles/slurm seeds
#
# Config keys (--config k=v):
#   seeds         comma-separated seeds (default: seed_table.seeds of conf/config.yaml)
#   seed_systems  comma-separated systems of the `seeds` target (default toy)
# Each seed is a whole results tree, results/seeds/seed<k>/<system>/ (clip.npz, stage1.pt, chart.npz,
# stage2.pt, metrics.json, figures/rollout.png), written by `python -m lagsplat all seed=<k>
# results_dir=results/seeds/seed<k>`; the table is results/tables/<system>_seeds.md and .csv.

_SEED_TABLE = _CONF["seed_table"]  # conf/config.yaml, read by the Snakefile
SEEDS = [int(s) for s in _csv(config.get("seeds", _SEED_TABLE["seeds"]))]
SEED_SYSTEMS = _csv(config.get("seed_systems", "toy"))
SEED_ROOT = f"{RESULTS}/{_SEED_TABLE['dir']}"
# one seed's results tree, results/seeds/seed<k>/<system>/, and what seed_run writes there
SEED_ART = Artifacts.at(f"{SEED_ROOT}/seed{{seed}}/{{system}}")
SEED_OUTPUTS = ("clip", "stage1", "chart", "stage2", "metrics", "rollout_figure")


rule seed_run:
    """ingest .. figures for one system with one seed (python -m lagsplat all), in its own results tree; the
    source file and every artifact it writes handed as artifacts.<name>."""
    input:
        unpack(lambda w: ingest_input(w.system)),
    output:
        **{n: str(getattr(SEED_ART, n)) for n in SEED_OUTPUTS},
    log:
        f"{RESULTS}/logs/seeds/seed{{seed}}/{{system}}.log",
    wildcard_constraints:
        seed="[0-9]+",
    threads: 2
    resources:
        mem_mb=8000,
        runtime=240,
    params:
        inputs=named_inputs,
    shell:
        f"NUMBA_NUM_THREADS={{threads}} python -m lagsplat all system={{wildcards.system}} raw_dir={RAW} "
        f"results_dir={SEED_ROOT}/seed{{wildcards.seed}} threads={{threads}} {{params.inputs}} "
        + " ".join(f"artifacts.{n}={{output.{n}}}" for n in SEED_OUTPUTS)
        + f" {OVR} seed={{wildcards.seed}} > {{log}} 2>&1"


rule seed_table:
    """Per-seed metrics of one system and their mean, std, min and max (python -m lagsplat seed_table)."""
    input:
        table_inputs=lambda w: [str(SEED_ART.metrics).format(seed=s, system=w.system) for s in SEEDS],
    output:
        table_md=f"{RESULTS}/tables/{{system}}_seeds.md",
        table_csv=f"{RESULTS}/tables/{{system}}_seeds.csv",
    log:
        f"{RESULTS}/logs/tables/{{system}}_seeds.log",
    params:
        seeds=",".join(str(s) for s in SEEDS),
        table_inputs=joined("table_inputs"),
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    shell:
        cli("seed_table", outputs=["table_md", "table_csv"], lists=["table_inputs"],
            extra=f"'seed_table.seeds=[{{params.seeds}}]' seed_table.dir={_SEED_TABLE['dir']}")


rule seeds:
    """The seed tables of --config seed_systems (default toy) over --config seeds."""
    input:
        [f"{RESULTS}/tables/{s}_seeds.md" for s in SEED_SYSTEMS],


localrules:
    seed_table,

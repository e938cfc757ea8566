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


rule seed_run:
    """ingest .. figures for one system with one seed (python -m lagsplat all), in its own results tree."""
    input:
        lambda w: raw_input(w.system),
    output:
        f"{SEED_ROOT}/seed{{seed}}/{{system}}/clip.npz",
        f"{SEED_ROOT}/seed{{seed}}/{{system}}/stage1.pt",
        f"{SEED_ROOT}/seed{{seed}}/{{system}}/chart.npz",
        f"{SEED_ROOT}/seed{{seed}}/{{system}}/stage2.pt",
        f"{SEED_ROOT}/seed{{seed}}/{{system}}/metrics.json",
        f"{SEED_ROOT}/seed{{seed}}/{{system}}/figures/rollout.png",
    log:
        f"{RESULTS}/logs/seeds/seed{{seed}}/{{system}}.log",
    wildcard_constraints:
        seed="[0-9]+",
    threads: 2
    resources:
        mem_mb=8000,
        runtime=240,
    shell:
        f"NUMBA_NUM_THREADS={{threads}} python -m lagsplat all system={{wildcards.system}} raw_dir={RAW} "
        f"results_dir={SEED_ROOT}/seed{{wildcards.seed}} threads={{threads}} {OVR} seed={{wildcards.seed}} > {{log}} 2>&1"


rule seed_table:
    """Per-seed metrics of one system and their mean, std, min and max (python -m lagsplat seed_table)."""
    input:
        lambda w: [f"{SEED_ROOT}/seed{s}/{w.system}/metrics.json" for s in SEEDS],
    output:
        f"{RESULTS}/tables/{{system}}_seeds.md",
        f"{RESULTS}/tables/{{system}}_seeds.csv",
    log:
        f"{RESULTS}/logs/tables/{{system}}_seeds.log",
    params:
        seeds=",".join(str(s) for s in SEEDS),
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    shell:
        f"python -m lagsplat seed_table system={{wildcards.system}} 'seed_table.seeds=[{{params.seeds}}]' "
        f"seed_table.dir={_SEED_TABLE['dir']} results_dir={RESULTS} {OVR} > {{log}} 2>&1"


rule seeds:
    """The seed tables of --config seed_systems (default toy) over --config seeds."""
    input:
        [f"{RESULTS}/tables/{s}_seeds.md" for s in SEED_SYSTEMS],


localrules:
    seed_table,

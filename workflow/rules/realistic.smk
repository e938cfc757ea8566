# The realistic suite: clips of a pendulum, a spring cart, a torsion disk and a double pendulum rendered by
# MuJoCo (an independent renderer) with a textured backdrop, moving shadows, distractors, a lighting
# gradient, sensor noise and MP4 compression, with per-frame ground truth (lagsplat.synth.realistic).
#
#   snakemake -c2 realistic_suite                                   # every clip, into the cache folder
#   snakemake -c2 realistic_suite --config realistic_dir=/scratch/clips
#   snakemake -c2 realistic_nuisance                                # the nuisance clips (distractor, sticks, short, long string)
#   snakemake -c2 realistic_backdrops                               # the backdrop clips (other walls, distractors, object sizes)
#   snakemake -c2 realistic_impacts                                 # the impact clips (bouncing off rigid stops, restitution < 1)
#
# Config keys: realistic_dir (default data/cache/realistic; not committed); realistic_args (extra flags of
# every scoring job, e.g. "--diagnose --true-law": the diagnosis too, scored against the clip's effect, and the
# clip's ground-truth law in its chart, benchmarks/_oracle.py). One job per clip, each logged.
#   snakemake -c2 realistic_short_scores   # the diagnosis with the training part cut to three periods (after realistic_scores)
from lagsplat.synth.realistic import backdrop_clips, impact_clips, nuisance_clips, outside_class_clips, realistic_suite

REALISTIC_DIR = str(config.get("realistic_dir", "data/cache/realistic"))
REALISTIC_CLIPS = [e["name"] for e in realistic_suite()]
OUTSIDE_CLASS_CLIPS = [e["name"] for e in outside_class_clips()]  # rendered with the suite; the pipeline must stop on them
NUISANCE_CLIPS = [e["name"] for e in nuisance_clips()]  # what the clip preparation is measured on; not scored
BACKDROP_CLIPS = [e["name"] for e in backdrop_clips()]  # held out for Stage 1: other backdrops, distractors, object sizes
IMPACT_CLIPS = [e["name"] for e in impact_clips()]  # impact oscillators (rigid stops, restitution < 1); test half frozen


rule realistic_clip:
    """One clip of the realistic suite: <clip>.mp4 and its ground truth <clip>.truth.npz."""
    output:
        mp4=f"{REALISTIC_DIR}/{{clip}}.mp4",
        truth=f"{REALISTIC_DIR}/{{clip}}.truth.npz",
    log:
        f"{RESULTS}/logs/realistic/{{clip}}.log",
    wildcard_constraints:
        clip="|".join(re.escape(c) for c in REALISTIC_CLIPS + OUTSIDE_CLASS_CLIPS + NUISANCE_CLIPS + BACKDROP_CLIPS + IMPACT_CLIPS),
    threads: 1
    shell:
        f"python -m lagsplat.synth.realistic --clip {{wildcards.clip}} --out {REALISTIC_DIR} > {{log}} 2>&1"


rule realistic_suite:
    """Every clip of the realistic suite, and the clips of motions outside the model class."""
    input:
        [f"{REALISTIC_DIR}/{c}.mp4" for c in REALISTIC_CLIPS + OUTSIDE_CLASS_CLIPS],


rule realistic_nuisance:
    """The nuisance clips (lagsplat.synth.realistic.nuisance): a distractor at the frame's edge, a motion that
    sticks, a clip of 2.5 periods, a long string; each with its observed frequency in <clip>.truth.npz."""
    input:
        [f"{REALISTIC_DIR}/{c}.mp4" for c in NUISANCE_CLIPS],


rule realistic_backdrops:
    """The backdrop clips (lagsplat.synth.realistic.backdrops): the suite's oscillators in front of a checker, wood,
    photographs or a cluttered wall, with other props, a turning fan or swaying plant, a moving light, and objects
    half to twice the suite's size; each with the suite's truth keys in <clip>.truth.npz."""
    input:
        [f"{REALISTIC_DIR}/{c}.mp4" for c in BACKDROP_CLIPS],


rule realistic_impacts:
    """The impact clips (lagsplat.synth.realistic.impacts): a pendulum, spring cart or torsion disk bouncing off one or
    two rigid stops drawn in the scene, restitution 0.3 to 0.9; each with its impacts and observed frequency in
    <clip>.truth.npz (truth_json)."""
    input:
        [f"{REALISTIC_DIR}/{c}.mp4" for c in IMPACT_CLIPS],


REALISTIC_ROWS = f"{RESULTS}/benchmarks/realistic"


rule realistic_row:
    """The pipeline on one realistic clip, as a new user runs it (conf/system/realistic.yaml), scored against
    the ground truth (benchmarks/realistic.py): a row with the frequency error, or the stage's one-line reason."""
    input:
        mp4=f"{REALISTIC_DIR}/{{clip}}.mp4",
        truth=f"{REALISTIC_DIR}/{{clip}}.truth.npz",
    output:
        f"{REALISTIC_ROWS}/{{clip}}.json",
    log:
        f"{RESULTS}/logs/realistic_runs/{{clip}}.log",
    wildcard_constraints:
        clip="|".join(re.escape(c) for c in REALISTIC_CLIPS),
    params:
        extra=str(config.get("realistic_args", "")),
    threads: 2
    shell:
        f"python benchmarks/realistic.py --clip {{wildcards.clip}} --clips {REALISTIC_DIR} --results {RESULTS}/realistic "
        f"--threads {{threads}} --row {{output}} {{params.extra}} > {{log}} 2>&1"


rule realistic_scores:
    """The realistic suite's score: results/benchmarks/realistic.md and .json."""
    input:
        [f"{REALISTIC_ROWS}/{c}.json" for c in REALISTIC_CLIPS],
    output:
        md=f"{RESULTS}/benchmarks/realistic.md",
        json=f"{RESULTS}/benchmarks/realistic.json",
    log:
        f"{RESULTS}/logs/benchmarks/realistic.log",
    shell:
        "python benchmarks/realistic.py --gather {input} --out {output.md} > {log} 2>&1"


REALISTIC_SHORT_ROWS = f"{RESULTS}/benchmarks/realistic_short"


rule realistic_short_row:
    """The diagnosis on one realistic clip whose training part is cut to three true periods (benchmarks/realistic.py,
    "Short clips"): the full run's Stage-1 autoencoder, the split moved, ingest to diagnosis again; then the clip's
    true law in the short run's chart (--true-law)."""
    input:
        row=f"{REALISTIC_ROWS}/{{clip}}.json",
        truth=f"{REALISTIC_DIR}/{{clip}}.truth.npz",
    output:
        f"{REALISTIC_SHORT_ROWS}/{{clip}}.json",
    log:
        f"{RESULTS}/logs/realistic_short_runs/{{clip}}.log",
    wildcard_constraints:
        clip="|".join(re.escape(c) for c in REALISTIC_CLIPS),
    threads: 2
    shell:
        f"python benchmarks/realistic.py --clip {{wildcards.clip}} --clips {REALISTIC_DIR} --from-results {RESULTS}/realistic "
        f"--results {RESULTS}/realistic_short --train-periods 3 --true-law --threads {{threads}} --row {{output}} > {{log}} 2>&1"


rule realistic_short_scores:
    """The diagnosis on the realistic suite cut to three training periods: results/benchmarks/realistic_short.md and .json."""
    input:
        [f"{REALISTIC_SHORT_ROWS}/{c}.json" for c in REALISTIC_CLIPS],
    output:
        md=f"{RESULTS}/benchmarks/realistic_short.md",
        json=f"{RESULTS}/benchmarks/realistic_short.json",
    log:
        f"{RESULTS}/logs/benchmarks/realistic_short.log",
    shell:
        "python benchmarks/realistic.py --gather {input} --out {output.md} > {log} 2>&1"

rule figures:
    """Rollout figure (paper Fig. 3 protocol)."""
    input:
        clip=str(ART.clip),
        stage1=str(ART.stage1),
        chart=str(ART.chart),
        stage2=str(ART.stage2),
        metrics=str(ART.metrics),
    output:
        rollout_figure=str(ART.rollout_figure),
    log:
        f"{RESULTS}/logs/{{system}}/figures.log",
    threads: 1
    shell:
        cli("figures", ["clip", "stage1", "chart", "stage2", "metrics"], ["rollout_figure"])


rule forces:
    """Force-transport checks and figure (paper §3.4, Fig. 7): background, linearity, kernel."""
    input:
        clip=str(ART.clip),
        stage1=str(ART.stage1),
        chart=str(ART.chart),
        stage2=str(ART.stage2),
    output:
        forces=str(ART.forces),
        forces_figure=str(ART.forces_figure),
    log:
        f"{RESULTS}/logs/{{system}}/forces.log",
    threads: 1
    shell:
        cli("forces", ["clip", "stage1", "chart", "stage2"], ["forces", "forces_figure"])


rule table:
    """A table rebuilt from metrics.json files (paper Table 2 layout)."""
    input:
        lambda w: [f"{RESULTS}/{s}/metrics.json" for s in TABLES[w.table]],
        lambda w: [f"{RESULTS}/{s}/figures/rollout.png" for s in TABLES[w.table]],
    output:
        f"{RESULTS}/tables/{{table}}.tex",
        f"{RESULTS}/tables/{{table}}.csv",
    wildcard_constraints:
        table="|".join(TABLES),
    log:
        f"{RESULTS}/logs/tables/{{table}}.log",
    params:
        systems=lambda w: ",".join(TABLES[w.table]),
    shell:
        f"python -m lagsplat table table.name={{wildcards.table}} 'table.systems=[{{params.systems}}]' results_dir={RESULTS} {OVR} > {{log}} 2>&1"


rule ablation_table:
    """Variants of one system side by side, e.g. results/tables/two_carts_inertia.tex
    (learned, decoder-induced and constant inertia on the same frozen chart)."""
    input:
        lambda w: [f"{RESULTS}/{w.system}/variants/{r}/metrics.json" for v in ABLATIONS[w.ablation] for r in seeded_variants(v, ABLATION_SEEDS)],
    output:
        f"{RESULTS}/tables/{{system}}_{{ablation}}.tex",
        f"{RESULTS}/tables/{{system}}_{{ablation}}.csv",
    wildcard_constraints:
        ablation="|".join(ABLATIONS),
        system="[a-z0-9_]+?",
    log:
        f"{RESULTS}/logs/tables/{{system}}_{{ablation}}.log",
    shell:
        f"python -m lagsplat ablation system={{wildcards.system}} ablation={{wildcards.ablation}} 'ablation_seeds={json.dumps(ABLATION_SEEDS)}' "
        f"results_dir={RESULTS} {OVR} > {{log}} 2>&1"


rule extrapolation:
    """LaGSplat, a latent neural ODE (no prior) and GP-2D (GaussianPrediction's structure) predict the held-out frames and 1000 s past them (paper §4.3)."""
    input:
        clip=str(ART.clip),
        stage1=str(ART.stage1),
        chart=str(ART.chart),
        stage2=str(ART.stage2),
    output:
        extrapolation=str(ART.extrapolation),
        extrapolation_figure=str(ART.extrapolation_figure),
    log:
        f"{RESULTS}/logs/{{system}}/extrapolation.log",
    threads: 2
    shell:
        cli("extrapolation", ["clip", "stage1", "chart", "stage2"], ["extrapolation", "extrapolation_figure"])


EXTRAPOLATION_SYSTEMS = ["toy", "oscillating_cart", "red_apple_pendulum"]


rule extrapolation_table:
    """Paper Table 3 layout: results/tables/extrapolation.tex, .csv and .md over the toy, the oscillating cart and the apple."""
    input:
        [f"{RESULTS}/{s}/extrapolation.json" for s in EXTRAPOLATION_SYSTEMS],
    output:
        f"{RESULTS}/tables/extrapolation.tex",
        f"{RESULTS}/tables/extrapolation.csv",
        f"{RESULTS}/tables/extrapolation.md",
    log:
        f"{RESULTS}/logs/tables/extrapolation.log",
    shell:
        f"python -m lagsplat extrapolation_table 'table.systems=[{','.join(EXTRAPOLATION_SYSTEMS)}]' results_dir={RESULTS} {OVR} > {{log}} 2>&1"


DEFORMATION_SYSTEM = "oscillating_cart"


rule deformation_table:
    """Paper App. B: the conditioned decoder against a deformation-field decoder at equal budget on the oscillating
    cart (the deformation variant's Stage 1 is trained inside the job, under variants/deformation/) ->
    results/tables/deformation.tex, .csv, .json and the velocity-field figure."""
    input:
        clip=str(ART.clip).format(system=DEFORMATION_SYSTEM),
        stage1=str(ART.stage1).format(system=DEFORMATION_SYSTEM),
        chart=str(ART.chart).format(system=DEFORMATION_SYSTEM),
    output:
        f"{RESULTS}/tables/deformation.tex",
        f"{RESULTS}/tables/deformation.csv",
        f"{RESULTS}/tables/deformation.json",
        str(ART.deformation_figure).format(system=DEFORMATION_SYSTEM),
        str(ART.decoder_variant("deformation").stage1).format(system=DEFORMATION_SYSTEM),  # the variant's Stage 1, trained by the job
    log:
        f"{RESULTS}/logs/tables/deformation.log",
    threads: 1
    shell:
        f"python -m lagsplat deformation system={DEFORMATION_SYSTEM} raw_dir={RAW} results_dir={RESULTS} threads={{threads}} "
        f"artifacts.clip={{input.clip}} artifacts.stage1={{input.stage1}} artifacts.chart={{input.chart}} "
        f"artifacts.deformation_figure={{output[3]}} deformation.table=deformation {OVR} > {{log}} 2>&1"

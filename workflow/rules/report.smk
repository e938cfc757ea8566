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
        table_inputs=lambda w: [str(ART.metrics).format(system=s) for s in TABLES[w.table]],
        figures=lambda w: [str(ART.rollout_figure).format(system=s) for s in TABLES[w.table]],
    output:
        table_tex=f"{RESULTS}/tables/{{table}}.tex",
        table_csv=f"{RESULTS}/tables/{{table}}.csv",
    wildcard_constraints:
        table="|".join(TABLES),
    log:
        f"{RESULTS}/logs/tables/{{table}}.log",
    params:
        systems=lambda w: ",".join(TABLES[w.table]),
        table_inputs=joined("table_inputs"),
    shell:
        cli("table", outputs=["table_tex", "table_csv"], lists=["table_inputs"], system=None,
            extra="table.name={wildcards.table} 'table.systems=[{params.systems}]'")


rule ablation_table:
    """Variants of one system side by side, e.g. results/tables/two_carts_inertia.tex
    (learned, decoder-induced and constant inertia on the same frozen chart)."""
    input:
        # in the stage's row order: each variant's runs (<variant>@seed<k> with ablation_seeds)
        table_inputs=lambda w: [str(VAR.metrics).format(system=w.system, variant=r) for v in ABLATIONS[w.ablation] for r in seeded_variants(v, ABLATION_SEEDS)],
    output:
        table_tex=f"{RESULTS}/tables/{{system}}_{{ablation}}.tex",
        table_csv=f"{RESULTS}/tables/{{system}}_{{ablation}}.csv",
    wildcard_constraints:
        ablation="|".join(ABLATIONS),
        system="[a-z0-9_]+?",
    log:
        f"{RESULTS}/logs/tables/{{system}}_{{ablation}}.log",
    params:
        table_inputs=joined("table_inputs"),
    shell:
        cli("ablation", outputs=["table_tex", "table_csv"], lists=["table_inputs"],
            extra=f"ablation={{wildcards.ablation}} 'ablation_seeds={json.dumps(ABLATION_SEEDS)}'")


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
        table_inputs=[str(ART.extrapolation).format(system=s) for s in EXTRAPOLATION_SYSTEMS],
    output:
        table_tex=f"{RESULTS}/tables/extrapolation.tex",
        table_csv=f"{RESULTS}/tables/extrapolation.csv",
        table_md=f"{RESULTS}/tables/extrapolation.md",
    log:
        f"{RESULTS}/logs/tables/extrapolation.log",
    params:
        table_inputs=joined("table_inputs"),
    shell:
        cli("extrapolation_table", outputs=["table_tex", "table_csv", "table_md"], lists=["table_inputs"], system=None,
            extra=f"'table.systems=[{','.join(EXTRAPOLATION_SYSTEMS)}]'")


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
        table_tex=f"{RESULTS}/tables/deformation.tex",
        table_csv=f"{RESULTS}/tables/deformation.csv",
        table_json=f"{RESULTS}/tables/deformation.json",
        deformation_figure=str(ART.deformation_figure).format(system=DEFORMATION_SYSTEM),
        deformation_stage1=str(ART.deformation_stage1).format(system=DEFORMATION_SYSTEM),  # the variant's Stage 1, trained by the job
    log:
        f"{RESULTS}/logs/tables/deformation.log",
    threads: 1
    shell:
        cli("deformation", ["clip", "stage1", "chart"], ["table_tex", "table_csv", "table_json", "deformation_figure", "deformation_stage1"],
            system=DEFORMATION_SYSTEM)

rule diagnose:
    """Sim-to-real gap diagnosis: which unmodelled effect, where it shows (time, state,
    latent directions, image), and the held-out gap before / after a Stage-2 refit with it.
    Writes results/<system>/diagnosis/{report.md, report.json, figures/*.png, refit.pt}."""
    input:
        clip=str(ART.clip),
        stage1=str(ART.stage1),
        chart=str(ART.chart),
        stage2=str(ART.stage2),
        metrics=str(ART.metrics),
    output:
        report_md=str(ART.report_md),
        report_json=str(ART.report_json),
    log:
        f"{RESULTS}/logs/{{system}}/diagnose.log",
    params:
        diagnosis=str(ART.diagnosis),
    threads: 2
    shell:
        cli("diagnose", ["clip", "stage1", "chart", "stage2", "metrics"], [], "artifacts.diagnosis={params.diagnosis}")

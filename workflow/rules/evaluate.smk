rule evaluate:
    """eps_freq, eps_q, eps_I / eps_AE on the held-out frames (paper §4.1)."""
    input:
        clip=str(ART.clip),
        stage1=str(ART.stage1),
        chart=str(ART.chart),
        stage2=str(ART.stage2),
    output:
        metrics=str(ART.metrics),
    log:
        f"{RESULTS}/logs/{{system}}/evaluate.log",
    threads: 2
    shell:
        cli("evaluate", ["clip", "stage1", "chart", "stage2"], ["metrics"])


rule evaluate_variant:
    """Metrics of an ablation variant, same protocol as ``evaluate``."""
    input:
        clip=str(VAR.clip),
        stage1=str(VAR.stage1),
        chart=str(VAR.chart),
        stage2=str(VAR.stage2),
    output:
        metrics=str(VAR.metrics),
    log:
        f"{RESULTS}/logs/{{system}}/variants/{{variant}}/evaluate.log",
    threads: 2
    shell:
        cli("evaluate", ["clip", "stage1", "chart", "stage2"], ["metrics"], "variant={wildcards.variant}")

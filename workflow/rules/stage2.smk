rule stage2:
    """Latent Lagrangian fitted on the frozen chart (paper §3.3, Eq. 8)."""
    input:
        chart=str(ART.chart),
        stage1=str(ART.stage1),  # the decoder-induced inertia reads the decoder
    output:
        stage2=str(ART.stage2),
    log:
        f"{RESULTS}/logs/{{system}}/stage2.log",
    threads: 2
    shell:
        cli("stage2", ["chart", "stage1"], ["stage2"])


rule stage2_variant:
    """An ablation on the same frozen chart (``variants`` in conf/config.yaml),
    e.g. results/two_carts/variants/mass_decoder/stage2.pt."""
    input:
        chart=str(VAR.chart),
        stage1=str(VAR.stage1),
    output:
        stage2=str(VAR.stage2),
    log:
        f"{RESULTS}/logs/{{system}}/variants/{{variant}}/stage2.log",
    threads: 2
    shell:
        cli("stage2", ["chart", "stage1"], ["stage2"], "variant={wildcards.variant}")

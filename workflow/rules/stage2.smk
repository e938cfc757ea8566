rule stage2:
    """Latent Lagrangian fitted on the frozen chart (paper §3.3, Eq. 8)."""
    input:
        f"{RESULTS}/{{system}}/chart.npz",
        f"{RESULTS}/{{system}}/stage1.pt",  # the decoder-induced inertia reads the decoder
    output:
        f"{RESULTS}/{{system}}/stage2.pt",
    log:
        f"{RESULTS}/logs/{{system}}/stage2.log",
    threads: 2
    shell:
        cli("stage2") + SHOW_LOG


rule stage2_variant:
    """An ablation on the same frozen chart (``variants`` in conf/config.yaml),
    e.g. results/two_carts/variants/mass_decoder/stage2.pt."""
    input:
        f"{RESULTS}/{{system}}/chart.npz",
        f"{RESULTS}/{{system}}/stage1.pt",
    output:
        f"{RESULTS}/{{system}}/variants/{{variant}}/stage2.pt",
    log:
        f"{RESULTS}/logs/{{system}}/variants/{{variant}}/stage2.log",
    threads: 2
    shell:
        cli("stage2") + " variant={wildcards.variant}" + SHOW_LOG

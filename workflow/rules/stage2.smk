rule stage2:
    """Latent Lagrangian fitted on the frozen chart (paper §3.3, Eq. 8)."""
    input:
        f"{RESULTS}/{{system}}/chart.npz",
        f"{RESULTS}/{{system}}/stage1.pt",  # the decoder-induced inertia reads the decoder
    output:
        f"{RESULTS}/{{system}}/stage2.pt",
    threads: 2
    shell:
        cli("stage2")

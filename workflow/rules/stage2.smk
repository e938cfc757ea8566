rule stage2:
    """Latent Lagrangian fitted on the frozen chart (paper §3.3, Eq. 8)."""
    input:
        f"{RESULTS}/{{system}}/chart.npz",
    output:
        f"{RESULTS}/{{system}}/stage2.pt",
    threads: 2
    shell:
        cli("stage2")

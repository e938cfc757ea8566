rule stage1:
    """Joint encoder / conditioned-Gaussian decoder training (paper §3.2)."""
    input:
        f"{RESULTS}/{{system}}/clip.npz",
    output:
        f"{RESULTS}/{{system}}/stage1.pt",
    threads: 2
    shell:
        cli("stage1")

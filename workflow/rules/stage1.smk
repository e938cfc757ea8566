rule stage1:
    """Joint encoder / conditioned-Gaussian decoder training (paper §3.2)."""
    input:
        f"{RESULTS}/{{system}}/clip.npz",
    output:
        f"{RESULTS}/{{system}}/stage1.pt",
    log:
        f"{RESULTS}/logs/{{system}}/stage1.log",
    threads: 2
    shell:
        cli("stage1") + SHOW_LOG

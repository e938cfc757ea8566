rule stage1:
    """Joint encoder / conditioned-Gaussian decoder training (paper §3.2)."""
    input:
        clip=str(ART.clip),
    output:
        stage1=str(ART.stage1),
    log:
        f"{RESULTS}/logs/{{system}}/stage1.log",
    threads: 2
    shell:
        cli("stage1", ["clip"], ["stage1"])

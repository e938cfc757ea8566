rule chart:
    """Whitening, visibility metric G_bar, loss metric A, AE floor (paper §3.2)."""
    input:
        clip=str(ART.clip),
        stage1=str(ART.stage1),
    output:
        chart=str(ART.chart),
    log:
        f"{RESULTS}/logs/{{system}}/chart.log",
    threads: 2
    shell:
        cli("chart", ["clip", "stage1"], ["chart"])

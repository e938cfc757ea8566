rule chart:
    """Whitening, visibility metric G_bar, loss metric A, AE floor (paper §3.2)."""
    input:
        f"{RESULTS}/{{system}}/clip.npz",
        f"{RESULTS}/{{system}}/stage1.pt",
    output:
        f"{RESULTS}/{{system}}/chart.npz",
    log:
        f"{RESULTS}/logs/{{system}}/chart.log",
    threads: 2
    shell:
        cli("chart") + SHOW_LOG

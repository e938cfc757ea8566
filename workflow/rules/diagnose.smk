rule diagnose:
    """Sim-to-real gap diagnosis: which unmodelled effect, where it shows (time, state,
    latent directions, image), and the held-out gap before / after a Stage-2 refit with it.
    Writes results/<system>/diagnosis/{report.md, report.json, figures/*.png, refit.pt}."""
    input:
        f"{RESULTS}/{{system}}/clip.npz",
        f"{RESULTS}/{{system}}/stage1.pt",
        f"{RESULTS}/{{system}}/chart.npz",
        f"{RESULTS}/{{system}}/stage2.pt",
        f"{RESULTS}/{{system}}/metrics.json",
    output:
        f"{RESULTS}/{{system}}/diagnosis/report.md",
        f"{RESULTS}/{{system}}/diagnosis/report.json",
    log:
        f"{RESULTS}/logs/{{system}}/diagnose.log",
    threads: 2
    shell:
        cli("diagnose") + SHOW_LOG

rule evaluate:
    """eps_freq, eps_q, eps_I / eps_AE on the held-out frames (paper §4.1)."""
    input:
        f"{RESULTS}/{{system}}/clip.npz",
        f"{RESULTS}/{{system}}/stage1.pt",
        f"{RESULTS}/{{system}}/chart.npz",
        f"{RESULTS}/{{system}}/stage2.pt",
    output:
        f"{RESULTS}/{{system}}/metrics.json",
    log:
        f"{RESULTS}/logs/{{system}}/evaluate.log",
    threads: 2
    shell:
        cli("evaluate") + SHOW_LOG


rule evaluate_variant:
    """Metrics of an ablation variant, same protocol as ``evaluate``."""
    input:
        f"{RESULTS}/{{system}}/clip.npz",
        f"{RESULTS}/{{system}}/stage1.pt",
        f"{RESULTS}/{{system}}/chart.npz",
        f"{RESULTS}/{{system}}/variants/{{variant}}/stage2.pt",
    output:
        f"{RESULTS}/{{system}}/variants/{{variant}}/metrics.json",
    log:
        f"{RESULTS}/logs/{{system}}/variants/{{variant}}/evaluate.log",
    threads: 2
    shell:
        cli("evaluate") + " variant={wildcards.variant}" + SHOW_LOG

rule stage1:
    """Joint encoder / conditioned-Gaussian decoder training (paper §3.2); a 3-D system also reads its cached views."""
    input:
        unpack(lambda w: stage1_input(w.system)),
    output:
        stage1=str(ART.stage1),
    log:
        f"{RESULTS}/logs/{{system}}/stage1.log",
    params:
        inputs=named_inputs,
    threads: 2
    shell:
        cli("stage1", "params", ["stage1"])

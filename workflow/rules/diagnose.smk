def diagnose_inputs(wildcards):
    """The diagnosis reads the run's artifacts; when an earlier stage stopped (its results/<system>/stopped.json,
    written by the CLI: ingest refused the clip, Stage 2 refused a chart that failed the quality gate), it reads
    only that record and writes a cannot_diagnose report, so a batch of clips gets one report per clip (run the
    stages with --keep-going, then ask for the reports again). Decided when the DAG is built."""
    a = Artifacts.at(f"{RESULTS}/{wildcards.system}")
    stop = a.load_stopped()
    if stop is not None:
        return {"stopped": stop["path"]}
    return {"clip": str(a.clip), "stage1": str(a.stage1), "chart": str(a.chart), "stage2": str(a.stage2), "metrics": str(a.metrics)}


rule diagnose:
    """Sim-to-real gap diagnosis: which unmodelled effect, where it shows (time, state,
    latent directions, image), and the held-out gap before / after a Stage-2 refit with it.
    Writes results/<system>/diagnosis/{report.md, report.json, figures/*.png, refit.pt} (the folder of its
    outputs, artifacts.diagnosis); a run an earlier stage stopped gets a cannot_diagnose report with that
    stage's reason."""
    input:
        unpack(diagnose_inputs),
    output:
        report_md=str(ART.report_md),
        report_json=str(ART.report_json),
    log:
        f"{RESULTS}/logs/{{system}}/diagnose.log",
    params:
        inputs=named_inputs,
        diagnosis=lambda w, output: str(Path(output.report_md).parent),
    threads: 2
    shell:
        cli("diagnose", "params", extra="artifacts.diagnosis={params.diagnosis}")

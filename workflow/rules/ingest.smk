rule download:
    """Fetch a source clip (URL and SHA256 from conf/system/<name>.yaml) to {output} (artifacts.source); fails
    with one line saying what to download and where when offline (the log, repeated on stderr)."""
    output:
        source=f"{RAW}/{{file}}",
    wildcard_constraints:
        file="|".join(RAW_FILES) or "NONE",
    log:
        f"{RESULTS}/logs/download/{{file}}.log",
    params:
        system=lambda w: RAW_FILES[w.file],
    shell:
        f"python -m lagsplat download system={{params.system}} raw_dir={RAW} download.file={{wildcards.file}} artifacts.source={{output.source}} "
        f"{OVR} > {{log}} 2>&1 || {{{{ cat {{log}} >&2; exit 1; }}}}"


rule ingest:
    """Source clip -> clip.npz (frames, real timestamps, actuation, split); the source file is handed as
    artifacts.source (ingest_input), a procedural system has none."""
    input:
        unpack(lambda w: ingest_input(w.system)),
    output:
        clip=str(ART.clip),
    log:
        f"{RESULTS}/logs/{{system}}/ingest.log",
    params:
        inputs=named_inputs,
    threads: 1
    shell:
        cli("ingest", "params", ["clip"])

rule download:
    """Fetch a source clip (URL and SHA256 from conf/system/<name>.yaml); fails
    with one line saying what to download and where when offline (the log, repeated on stderr)."""
    output:
        f"{RAW}/{{file}}",
    wildcard_constraints:
        file="|".join(RAW_FILES) or "NONE",
    log:
        f"{RESULTS}/logs/download/{{file}}.log",
    params:
        system=lambda w: RAW_FILES[w.file],
    shell:
        f"python -m lagsplat download system={{params.system}} raw_dir={RAW} download.file={{wildcards.file}} {OVR} > {{log}} 2>&1 || {{{{ cat {{log}} >&2; exit 1; }}}}"


rule ingest:
    """Source clip -> clip.npz (frames, real timestamps, actuation, split)."""
    input:
        lambda w: raw_input(w.system),
    output:
        clip=str(ART.clip),
    log:
        f"{RESULTS}/logs/{{system}}/ingest.log",
    threads: 1
    shell:
        cli("ingest", [], ["clip"])

rule download:
    """Fetch a source clip (URL and SHA256 from conf/system/<name>.yaml); fails
    with one line saying what to download and where when offline."""
    output:
        f"{RAW}/{{file}}",
    wildcard_constraints:
        file="|".join(RAW_FILES) or "NONE",
    params:
        system=lambda w: RAW_FILES[w.file],
    shell:
        f"python -m lagsplat download system={{params.system}} raw_dir={RAW} download.file={{wildcards.file}} {OVR}"


rule ingest:
    """Source clip -> clip.npz (frames, real timestamps, actuation, split)."""
    input:
        lambda w: raw_input(w.system),
    output:
        f"{RESULTS}/{{system}}/clip.npz",
    threads: 1
    shell:
        cli("ingest")

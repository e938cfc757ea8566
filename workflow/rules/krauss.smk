# Soft continuum robot benchmark (Krauss et al. 2026; paper §4.4, Table 4).
#
#   snakemake -c2 results/tables/krauss.tex                     # real data (downloads ~4.5 GB once)
#   snakemake -c2 results/tables/krauss.tex --config krauss_archive=/path/processed_data.zip
#   snakemake -c2 results/tables/krauss.tex --config krauss_source=synthetic   # offline surrogate
#
# Config keys (--config k=v):
#   krauss_source   zenodo (default): Zenodo record 17812071, processed_data.zip, members verified by SHA256;
#                   synthetic: the simulated robot of lagsplat.synth.continuum_robot, systems
#                   krauss_{1seg,2seg}_synth (own results folders, rows labelled "surrogate").
#   krauss_archive  a local copy of processed_data.zip (nothing is downloaded; the file is only read).
#   krauss_synth_duration_s, krauss_synth_seed   override the surrogate's length (s) and seed.
# The extracted NPZ files can also be placed by hand in raw_dir
# (scr_dataset_raw_{1seg,2seg}_32x32_59fps.npz): an existing file skips the download.
# The chain per robot: archive -> NPZ -> ingest -> stage1 -> chart -> stage2 (+ the two-segment
# inertia variants) -> evaluate (system.protocol: krauss) -> krauss_table; robot_figures per robot.
#   snakemake -c2 krauss --config krauss_source=synthetic   # the table and both robots' figures
#   snakemake -c2 results/tables/krauss_surrogate.tex        # the surrogate's table whatever krauss_source says (paper target)

from lagsplat.report.paper import KRAUSS_SURROGATE, KRAUSS_SURROGATE_TABLE  # the surrogate's robots and their table

KRAUSS_SOURCE = str(config.get("krauss_source", "zenodo"))
if KRAUSS_SOURCE not in ("zenodo", "synthetic"):
    raise ValueError(f"--config krauss_source={KRAUSS_SOURCE!r}: use zenodo (default) or synthetic")
_KSFX = "" if KRAUSS_SOURCE == "zenodo" else "_synth"
KRAUSS = {"1seg": f"krauss_1seg{_KSFX}", "2seg": f"krauss_2seg{_KSFX}"}
KRAUSS_ABLATION = ["mass_decoder", "mass_constant"]  # paper §4.4, variants in conf/config.yaml



def _kmerge(a, b):
    """``b`` merged over ``a`` (nested dicts), as Hydra's defaults list does."""
    out = dict(a)
    for k, v in b.items():
        out[k] = _kmerge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def krauss_conf(name):
    """The system block of conf/system/<name>.yaml with its ``defaults`` parents merged in
    (the krauss_* files inherit from krauss_2seg.yaml)."""
    raw = yaml.safe_load((Path("conf/system") / f"{name}.yaml").read_text())
    base = {}
    for parent in raw.get("defaults") or []:
        if isinstance(parent, str) and parent != "_self_":
            base = _kmerge(base, krauss_conf(parent))
    return _kmerge(base, raw.get("system") or {})


# real data: NPZ file name -> system, all members of one archive
_KREAL = {krauss_conf(s)["source"]["file"]: s for s in ("krauss_1seg", "krauss_2seg")}
_KSRC = {f: krauss_conf(s)["source"] for f, s in _KREAL.items()}
KRAUSS_URL = next(iter(_KSRC.values()))["url"]
KRAUSS_ARCHIVE_FILE = next(iter(_KSRC.values()))["archive_file"]
KRAUSS_ARCHIVE = config.get("krauss_archive") or f"{RAW}/{KRAUSS_ARCHIVE_FILE}"
# surrogate: NPZ file name -> system
_KSYN = {krauss_conf(s)["source"]["file"]: s for s in ("krauss_1seg_synth", "krauss_2seg_synth")}


def _kre(names):
    return "|".join(n.replace(".", r"\.") for n in names)


def _krauss_projection():
    """Print the projected wall time of the planned soft-robot jobs before the first one starts
    (lagsplat.report.projection); a projection that cannot be made is skipped with one line, never an error."""
    import shlex

    from lagsplat.cli_common import apply_variant, compose
    from lagsplat.report.projection import project, projection_lines

    files = {**_KREAL, **_KSYN}
    base = [f"raw_dir={RAW}", f"results_dir={RESULTS}", *shlex.split(OVR)]
    cfgs, jobs = {}, []
    for j in workflow.dag.needrun_jobs():
        w = dict(j.wildcards)
        system = w.get("system") or files.get(w.get("file"))
        if system not in KRAUSS.values():
            continue
        key = (system, w.get("variant"))
        if key not in cfgs:  # one composition per system and variant, not per job
            cfgs[key] = apply_variant(compose([f"system={system}", *base] + ([f"variant={key[1]}"] if key[1] else [])))
        jobs.append((j.rule.name, system, cfgs[key]))
    for line in projection_lines(project(jobs, workflow.resource_settings.cores or 1)):
        print(line, flush=True)


ruleorder: krauss_extract > download
ruleorder: krauss_synth > download


rule krauss_archive:
    """Download processed_data.zip (Zenodo record 17812071, ~4.5 GB) once for both robots; offline,
    fails with one line saying what to download and where to put it. The archive has no published
    checksum; it must list both members, whose SHA256 krauss_extract verifies. Delete it once both
    NPZ files are extracted if disk space matters."""
    output:
        f"{RAW}/{KRAUSS_ARCHIVE_FILE}",
    params:
        members=" ".join(f"--member {s['member']}" for s in _KSRC.values()),
        hint="or pass a local copy with --config krauss_archive=PATH, or place the extracted "
        + " and ".join(f"{s['member']} at {RAW}/{f} (sha256 {s['sha256']})" for f, s in _KSRC.items()),
    log:
        f"{RESULTS}/logs/download/{KRAUSS_ARCHIVE_FILE}.log",
    shell:
        f"python -m lagsplat.io.zenodo archive '{KRAUSS_URL}' {{output}} {{params.members}} --hint '{{params.hint}}' > {{log}} 2>&1 || {{{{ cat {{log}} >&2; exit 1; }}}}"


rule krauss_extract:
    """Extract one robot's NPZ from the archive and verify its SHA256 (atomically; a mismatch leaves nothing)."""
    input:
        KRAUSS_ARCHIVE,
    output:
        source=f"{RAW}/{{file}}",
    wildcard_constraints:
        file=_kre(_KREAL),
    log:
        f"{RESULTS}/logs/download/{{file}}.log",
    params:
        system=lambda w: _KREAL[w.file],
    shell:
        f"python -m lagsplat download system={{params.system}} raw_dir={RAW} download.file={{wildcards.file}} download.archive={{input}} "
        f"artifacts.source={{output.source}} {OVR} > {{log}} 2>&1 || {{{{ cat {{log}} >&2; exit 1; }}}}"


rule krauss_synth:
    """The offline surrogate (lagsplat.synth.continuum_robot) in the Krauss NPZ layout, with its
    sidecar JSON (natural frequencies, depressurisation frame) used by the evaluation."""
    output:
        npz=f"{RAW}/{{file}}",
        truth=f"{RAW}/{{file}}.json",
    wildcard_constraints:
        file=_kre(_KSYN),
    params:
        segments=lambda w: krauss_conf(_KSYN[w.file])["source"]["generator"]["segments"],
        duration=lambda w: config.get("krauss_synth_duration_s", krauss_conf(_KSYN[w.file])["source"]["generator"]["duration_s"]),
        seed=lambda w: config.get("krauss_synth_seed", krauss_conf(_KSYN[w.file])["source"]["generator"]["seed"]),
    log:
        f"{RESULTS}/logs/krauss_synth/{{file}}.log",
    shell:
        "python -m lagsplat.synth.continuum_robot --segments {params.segments} --out {output.npz} --duration-s {params.duration} --seed {params.seed} > {log} 2>&1"


# table name -> its robots: krauss, those of --config krauss_source; krauss_surrogate, the offline surrogate's whatever
# krauss_source says (the paper target's soft-robot table, workflow/rules/paper.smk)
KRAUSS_TABLES = {"krauss": KRAUSS, KRAUSS_SURROGATE_TABLE: KRAUSS_SURROGATE}


def krauss_table_inputs(robots):
    """The metrics a soft-robot table reads, in the stage's row order: one segment, two segments, each ablation variant's runs."""
    return [str(ART.metrics).format(system=robots["1seg"]), str(ART.metrics).format(system=robots["2seg"])] + [
        str(VAR.metrics).format(system=robots["2seg"], variant=r) for v in KRAUSS_ABLATION for r in seeded_variants(v, ABLATION_SEEDS)
    ]


rule krauss_table:
    """Paper Table 4: published rows (lagsplat/report/data/krauss_published.csv) and ours, plus the
    two-segment inertia ablation (decoder-induced and constant M on the same frozen chart):
    results/tables/krauss.tex (the robots of krauss_source) or krauss_surrogate.tex (the surrogate's). It runs in the
    two-segment system's configuration, so that --config overrides written for the robots
    (e.g. system.source.sha256=... for a local archive) compose here as they do in every other job."""
    input:
        table_inputs=lambda w: krauss_table_inputs(KRAUSS_TABLES[w.ktable]),
    output:
        table_tex=f"{RESULTS}/tables/{{ktable}}.tex",
        table_csv=f"{RESULTS}/tables/{{ktable}}.csv",
        table_md=f"{RESULTS}/tables/{{ktable}}.md",
    wildcard_constraints:
        ktable="|".join(KRAUSS_TABLES),
    log:
        f"{RESULTS}/logs/tables/{{ktable}}.log",
    params:
        ablation=",".join(KRAUSS_ABLATION),
        table_inputs=joined("table_inputs"),
        one=lambda w: KRAUSS_TABLES[w.ktable]["1seg"],
        two=lambda w: KRAUSS_TABLES[w.ktable]["2seg"],
    shell:
        cli("krauss_table", outputs=["table_tex", "table_csv", "table_md"], lists=["table_inputs"], system="{params.two}",
            extra="krauss_table.name={wildcards.ktable} krauss_table.one_segment={params.one} krauss_table.two_segments={params.two} "
            f"'krauss_table.ablation=[{{params.ablation}}]' 'ablation_seeds={json.dumps(ABLATION_SEEDS)}'")


rule robot_figures:
    """The soft robot's figures (paper Figs. krauss-npz-rollout and krauss-force): a 30 s pressure-driven
    rollout on the held-out split decoded at 256x256, and loaded equilibria at the operating pressure."""
    input:
        clip=str(ART.clip),
        stage1=str(ART.stage1),
        chart=str(ART.chart),
        stage2=str(ART.stage2),
    output:
        robot_rollout_figure=str(ART.robot_rollout_figure),
        robot_forces_figure=str(ART.robot_forces_figure),
        robot_forces=str(ART.robot_forces),
    log:
        f"{RESULTS}/logs/{{system}}/robot_figures.log",
    threads: 1
    shell:
        cli("robot_figures", ["clip", "stage1", "chart", "stage2"], ["robot_rollout_figure", "robot_forces_figure", "robot_forces"])


rule krauss:
    """The whole soft-robot benchmark (see results/tables/krauss.tex) and both robots' figures."""
    input:
        f"{RESULTS}/tables/krauss.tex",
        [f"{RESULTS}/{s}/figures/robot_{f}.png" for s in KRAUSS.values() for f in ("rollout", "forces")],

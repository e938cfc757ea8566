"""Command line: ``python -m lagsplat <stage> system=<name> [hydra overrides]``.

One stage per Snakemake rule; each reads only upstream artifacts under
``${results_dir}/${system.name}/`` and writes its own atomically, with the
resolved configuration saved beside it (``config/<stage>.yaml``).

Stages: ``download``, ``ingest``, ``stage1``, ``chart``, ``stage2``,
``evaluate``, ``figures``, ``forces``, ``diagnose``, ``table``, ``ablation``, ``krauss_table``, ``seed_table``, ``all`` (ingest ->
figures in one process), and ``view`` (the interactive viewer, which writes
nothing).
"""

from __future__ import annotations

import inspect
import os
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from omegaconf import DictConfig, OmegaConf

if TYPE_CHECKING:
    from lagsplat.artifacts import Artifacts

__all__ = ["main", "compose", "find_conf_dir", "STAGES"]

USAGE = """usage: python -m lagsplat <stage> system=<name> [key=value ...]

stages:
  download   fetch the system's source clip (URL + SHA256 from conf/system/<name>.yaml)
  ingest     source clip -> results/<name>/clip.npz
  stage1     clip.npz -> stage1.pt           (encoder + conditioned-Gaussian decoder)
  chart      stage1.pt -> chart.npz          (whitening, G_bar, A, AE floor)
  stage2     chart.npz -> stage2.pt          (latent Lagrangian)
  evaluate   -> metrics.json                 (eps_freq, eps_q, eps_I / eps_AE; system.protocol=krauss:
             the published soft-robot protocol, lagsplat.evaluate.krauss)
  figures    -> figures/rollout.png
  forces     -> forces.json, figures/forces.png (force-transport checks: background, linearity, kernel)
  diagnose   -> diagnosis/report.md, report.json, figures/ (sim-to-real gap: which unmodelled effect,
             where it shows, held-out gap before / after a Stage-2 refit with it; lagsplat.diagnose)
  table      metrics.json of table.systems -> results/tables/<table.name>.tex/.csv
  ablation   variants' metrics.json of one system -> results/tables/<name>_<ablation>.tex/.csv
  krauss_table  soft-robot benchmark (paper Table 4) -> results/tables/krauss.tex/.csv/.md
  seed_table one system trained with each of seed_table.seeds (results/seeds/seed<k>/<name>/metrics.json)
             -> results/tables/<name>_seeds.md/.csv (per-seed rows, mean, std, min, max)
  all        ingest .. figures for one system
  view       interactive viewer: drag the identified model in a local web page
             (http://127.0.0.1:<view.port>/; settings in the `view` group of conf/config.yaml)

  variant=<name> (see `variants` in conf/config.yaml) runs stage2 / evaluate / figures
  as an ablation on the same frozen chart, into results/<name>/variants/<variant>/.

examples:
  python -m lagsplat all system=toy
  python -m lagsplat stage1 system=oscillating_cart stage1.steps=500
  python -m lagsplat table table.name=physical 'table.systems=[toy,oscillating_cart]'
  python -m lagsplat stage2 system=two_carts variant=mass_decoder
  python -m lagsplat view system=toy view.port=0
"""


def find_conf_dir() -> Path:
    """Locate the Hydra ``conf/`` folder.

    Order: ``$LAGSPLAT_CONF``, ``./conf`` in the working directory, then the
    ``conf/`` beside the package (a source checkout / editable install).

    Raises:
        FileNotFoundError: if none has a ``config.yaml``.
    """
    cands = [os.environ.get("LAGSPLAT_CONF"), Path.cwd() / "conf", Path(__file__).resolve().parents[1] / "conf"]
    for c in cands:
        if c and (Path(c) / "config.yaml").exists():
            return Path(c).resolve()
    raise FileNotFoundError("no conf/config.yaml found: run from the project root or set LAGSPLAT_CONF")


def compose(overrides: list[str]) -> DictConfig:
    """Compose the configuration (``conf/config.yaml`` + system + overrides)."""
    from hydra import compose as hcompose
    from hydra import initialize_config_dir

    from lagsplat.config_schema import register_schemas

    register_schemas()

    with initialize_config_dir(config_dir=str(find_conf_dir()), version_base=None):
        return hcompose(config_name="config", overrides=overrides)


def artifacts_of(cfg: DictConfig) -> "Artifacts":
    """The run's artifact paths (:class:`lagsplat.artifacts.Artifacts`): ``${results_dir}/<system>/``,
    the model's under ``variants/<variant>/`` when ``variant`` is set, each overridable as ``artifacts.<name>=PATH``."""
    from lagsplat.artifacts import Artifacts

    return Artifacts.for_run(cfg.results_dir, cfg.system.name, cfg.get("variant"), _container(cfg.get("artifacts") or {}))


def apply_variant(cfg: DictConfig) -> DictConfig:
    """Merge ``variants[cfg.variant]`` into ``cfg`` (no-op without a variant).

    Raises:
        KeyError: naming the unknown variant and the known ones.
    """
    v = cfg.get("variant")
    if not v:
        return cfg
    known = cfg.get("variants") or {}
    if v not in known:
        raise KeyError(f"unknown variant {v!r}; known: {sorted(known)} (conf/config.yaml, key variants)")
    return OmegaConf.merge(cfg, known[v])


def _save_cfg(cfg: DictConfig, stage: str) -> None:
    from lagsplat.io.atomic import atomic_write

    with atomic_write(artifacts_of(cfg).config(stage)) as tmp:
        tmp.write_text(OmegaConf.to_yaml(cfg, resolve=True))


def _container(node) -> dict:
    return OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)


# --------------------------------------------------------------------- stages
def stage_download(cfg: DictConfig) -> None:
    """Fetch the source clip(s) to ``source.path`` and verify their SHA256.

    With ``sources`` (several recordings) every entry with a ``url`` is
    fetched, or only the one whose ``file`` is ``download.file`` when set.
    """
    from lagsplat.io.download import fetch

    entries = list(cfg.system.get("sources") or []) or [cfg.system.source]
    dl = cfg.get("download") or {}
    only = dl.get("file")
    todo = [e for e in entries if e.get("url") and (not only or e.get("file") == only)]
    if not todo:
        print(f"{cfg.system.name}: nothing to download (no source.url)")
        return
    for src in todo:
        if src.get("member"):  # a file inside a zip archive (lagsplat.io.zenodo): the member's SHA256 is verified
            from lagsplat.io.zenodo import fetch_member

            cache = Path(cfg.raw_dir) / src.archive_file if src.get("archive_file") else None
            hint = "or give a local copy with download.archive=PATH (Snakemake: --config krauss_archive=PATH)"
            fetch_member(src.url, src.member, Path(src.path), src.sha256, archive=dl.get("archive"), cache=cache, hint=hint)
            continue
        fetch(src.url, Path(src.path), src.sha256)


def stage_ingest(cfg: DictConfig) -> None:
    """Source clip -> ``clip.npz``."""
    from lagsplat.ingest import ingest_to_file

    ingest_to_file(_container(cfg.system), artifacts_of(cfg).clip)
    _save_cfg(cfg, "ingest")


def stage_stage1(cfg: DictConfig) -> None:
    """``clip.npz`` -> ``stage1.pt``."""
    from lagsplat.models.autoencoder import save_stage1
    from lagsplat.train.stage1 import Stage1Config, train_stage1

    a = artifacts_of(cfg)
    clip = a.load_clip()
    s1 = Stage1Config.from_mapping(_container(cfg.stage1))
    model, hist = train_stage1(
        clip, s1, int(cfg.system.d), seed=int(cfg.seed), progress=bool(cfg.progress), device=str(cfg.device), label=f"{cfg.system.name} stage1"
    )
    save_stage1(a.stage1, model, _container(cfg.stage1), hist, int(cfg.system.d))
    _save_cfg(cfg, "stage1")


def stage_chart(cfg: DictConfig) -> None:
    """``stage1.pt`` -> ``chart.npz``."""
    from lagsplat.chart import build_chart, save_chart

    a = artifacts_of(cfg)
    chart = build_chart(
        a.load_stage1(), a.load_clip(), int(cfg.chart.n_metric_samples), float(cfg.chart.rho), int(cfg.seed),
        refine_iters=int(cfg.chart.get("refine_iters", 0)),
    )
    save_chart(a.chart, chart)
    _save_cfg(cfg, "chart")


def stage_stage2(cfg: DictConfig) -> None:
    """``chart.npz`` -> ``stage2.pt``."""
    from lagsplat.train.stage2 import Stage2Config, save_stage2, train_stage2

    a = artifacts_of(cfg)
    s2 = Stage2Config.from_mapping(_container(cfg.stage2))
    chart = a.load_chart()
    inertia = None
    if s2.mass == "decoder":  # parameter-free inertia from the frozen Stage-1 decoder (paper Eq. 7)
        from lagsplat.models.lagrangian import DecoderInertia

        ae = a.load_stage1()
        inertia = DecoderInertia.from_decoder(ae.decoder, chart.W_inv, chart.mean, chart.height, chart.width)
    model, hist = train_stage2(
        chart, s2, seed=int(cfg.seed), progress=bool(cfg.progress), inertia=inertia, device=str(cfg.device), label=f"{cfg.system.name} stage2"
    )
    save_stage2(a.stage2, model, s2, hist)
    _save_cfg(cfg, "stage2")


def stage_evaluate(cfg: DictConfig) -> None:
    """Upstream artifacts -> ``metrics.json``."""
    from lagsplat.evaluate import SETTINGS_GROUP, protocol_for, run_protocol
    from lagsplat.io.atomic import write_json

    a = artifacts_of(cfg)
    clip, chart = a.load_clip(), a.load_chart()
    model, ck = a.load_stage2()
    protocol = protocol_for(cfg.system)  # the published soft-robot protocol for system.protocol=krauss (paper §4.4, Table 4)
    settings = cfg.get(SETTINGS_GROUP[protocol])
    m = run_protocol(protocol, clip, a.load_stage1(), chart, model, _container(settings) if settings else {}, _container(cfg.system), str(a.clip))
    write_json(
        a.metrics,
        {
            "system": cfg.system.name,
            "variant": cfg.get("variant"),
            "protocol": protocol,
            "data": data_kind(cfg.system),
            "stage2": _container(cfg.stage2),
            "title": cfg.system.get("title", cfg.system.name),
            "d": int(cfg.system.d),
            "provenance": cfg.system.get("provenance", ""),
            "dt_s": float(clip.dt),
            "n_train": int(len(clip.train_idx)),
            "n_held_out": int(len(clip.held_out_idx)),
            "image_size": [chart.width, chart.height],
            "stage2_selected_epoch": ck["history"].get("selected_epoch"),
            "metrics": m,
        },
    )
    _save_cfg(cfg, "evaluate")


def stage_figures(cfg: DictConfig) -> None:
    """Upstream artifacts -> ``figures/rollout.png``."""
    from lagsplat.viz.rollout import rollout_figure

    title = str(cfg.system.get("title", cfg.system.name)) + (f" [{cfg.variant}]" if cfg.get("variant") else "")
    rollout_figure(artifacts_of(cfg), title=title, provenance=str(cfg.system.get("provenance", "")))


def stage_forces(cfg: DictConfig) -> None:
    """Force-transport checks (paper §3.4, Fig. 7) -> ``forces.json`` and ``figures/forces.png``.

    The figure and the top level of ``forces.json`` use the default brush
    (``brush``); ``other_brushes`` holds the background, linearity and kernel
    checks through the others (:data:`lagsplat.force.BRUSHES`).
    """
    import numpy as np
    import torch

    from lagsplat.force import BRUSHES, ForceTransport
    from lagsplat.force_checks import ForceCheckConfig, plot_force_checks, public_result, run_force_checks
    from lagsplat.io.atomic import write_json
    from lagsplat.train.config import dataclass_from_mapping

    a = artifacts_of(cfg)
    fc = dataclass_from_mapping(ForceCheckConfig, OmegaConf.to_container(cfg.get("forces", {}), resolve=True), "forces")
    ae, chart = a.load_stage1(), a.load_chart()
    model, _ = a.load_stage2()
    model.eval()
    tr = ForceTransport.from_autoencoder(ae, chart, min_transmittance=fc.min_transmittance)
    with torch.no_grad():
        z = model.q_rest.detach()[None] @ torch.as_tensor(chart.W_inv, dtype=torch.float32) + torch.as_tensor(chart.mean, dtype=torch.float32)
        rest = (ae.decode(z)[0].clamp(0, 1).permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)
    clip = a.load_clip()
    res = run_force_checks(model, tr, clip.images, rest, fc)
    lever = None
    if clip.meta.get("source") == "lagsplat.synth.pendulum":  # known pivot: the lever-arm profile along the rod
        from lagsplat.force_checks import lever_profile
        from lagsplat.synth.pendulum import PIVOT_Y, ROD_LENGTH

        H, W = ae.height, ae.width
        above = float(clip.meta.get("params", {}).get("rod_above", 0.0)) * H
        radii = np.linspace(-max(above - fc.sigma, 0.0), ROD_LENGTH * H, 25)
        force = (float(np.median(res["_maps"]["dq_obj"]) > 0) * res["force_px"], 0.0)
        lever = lever_profile(model, tr, (W / 2.0, PIVOT_Y * H), (0.0, 1.0), radii, force, fc.sigma)
        res["lever"] = {"r_px": lever["r"].tolist(), "f_lat": lever["f_lat"][:, 0].tolist(), "dq": lever["dq"][:, 0].tolist()}
    title = str(cfg.system.get("title", cfg.system.name)) + ": forces through J^T f"
    plot_force_checks(res, rest, a.forces_figure, title=title, lever=lever)
    pub = public_result(res)
    pub["brush"] = tr.brush
    pub["min_transmittance"] = tr.min_transmittance
    # the same checks through the other brush (lagsplat.force.BRUSHES), for comparison
    pub["other_brushes"] = {}
    for name in (b for b in BRUSHES if b != tr.brush):
        other = run_force_checks(model, ForceTransport.from_autoencoder(ae, chart, brush=name), clip.images, rest, fc)
        pub["other_brushes"][name] = {k: other[k] for k in ("background", "linearity", "kernel")}
    write_json(a.forces, pub)
    for name, r in {tr.brush: pub, **pub["other_brushes"]}.items():
        b, lin, ker = r["background"], r["linearity"], r["kernel"]
        gap = "exactly still" if b["ratio"] is None else f"{b['ratio']:.0f}x below the object"
        verdict = "pass" if b["passed"] else "FAIL"
        print(
            f"{cfg.system.name} ({name} brush): background {gap} ({verdict}, need {b['required_ratio']:g}x); "
            f"J^T f additivity {lin['f_lat_rel_err']:.1e}; kernel {ker['rel']:.1e}"
        )


def stage_diagnose(cfg: DictConfig) -> None:
    """Sim-to-real gap diagnosis -> ``diagnosis/report.md``, ``report.json``, ``figures/*.png``.

    Reads ``clip.npz``, ``stage1.pt``, ``chart.npz``, ``stage2.pt`` and
    ``metrics.json`` (of the variant when ``variant`` is set); settings in the
    ``diagnose`` group, the gap protocol in ``evaluate``; the refit uses the
    Stage-2 settings saved in ``stage2.pt``. See :mod:`lagsplat.diagnose.report`.
    """
    from lagsplat.diagnose.report import DiagnoseConfig, diagnose_system
    from lagsplat.evaluate import EvalConfig

    dc = DiagnoseConfig.from_mapping(_container(cfg.diagnose) if cfg.get("diagnose") else None)
    dc.refit.seed = int(cfg.seed)
    title = str(cfg.system.get("title", cfg.system.name)) + (f" [{cfg.variant}]" if cfg.get("variant") else "")
    a = artifacts_of(cfg)
    rep = diagnose_system(a, dc, EvalConfig(**_container(cfg.evaluate)), title, bool(cfg.progress))
    red = (rep["gap"].get("reduction") or {}).get("eps_q")
    print(
        f"{cfg.system.name}: {rep['verdict_text']}; held-out eps_q {rep['gap']['before']['eps_q']:.4f}"
        + (f" -> {rep['gap']['after']['eps_q']:.4f} ({100 * red:+.0f} %)" if red is not None else "")
        + f"; report: {a.report_md}"
    )
    from lagsplat.io.atomic import atomic_write

    with atomic_write(a.diagnosis_config) as tmp:  # beside the report: the stage writes only under diagnosis/
        tmp.write_text(OmegaConf.to_yaml(cfg, resolve=True))


def stage_table(cfg: DictConfig) -> None:
    """``metrics.json`` of ``table.systems`` -> ``results/tables/<table.name>.tex`` and ``.csv``."""
    from lagsplat.artifacts import table_path, variant_metrics_path
    from lagsplat.report.tables import physical_table

    t = cfg.get("table", {})
    name = t.get("name", "physical")
    systems = list(t.get("systems", [cfg.system.name]))
    inputs = [variant_metrics_path(cfg.results_dir, s, None) for s in systems]
    physical_table(inputs, table_path(cfg.results_dir, name))


def stage_ablation(cfg: DictConfig) -> None:
    """Variant ``metrics.json`` of one system -> ``results/tables/<system>_<ablation>.tex`` and ``.csv``."""
    from lagsplat.artifacts import table_path, variant_metrics_path
    from lagsplat.report.tables import ablation_table

    key = str(cfg.ablation)
    if key not in cfg.ablations:
        raise KeyError(f"unknown ablation {key!r}; known: {sorted(cfg.ablations)} (conf/config.yaml, key ablations)")
    inputs = [variant_metrics_path(cfg.results_dir, cfg.system.name, v) for v in cfg.ablations[key]]
    ablation_table(inputs, table_path(cfg.results_dir, f"{cfg.system.name}_{key}"))


def stage_seed_table(cfg: DictConfig) -> None:
    """One system trained with each of ``seed_table.seeds`` -> ``results/tables/<system>_seeds.md`` and ``.csv``.

    Reads ``${results_dir}/${seed_table.dir}/seed<k>/<system>/metrics.json``:
    the ``evaluate`` output of a run with ``seed=<k>
    results_dir=${results_dir}/${seed_table.dir}/seed<k>`` (the Snakemake
    rule ``seed_run``).
    """
    from lagsplat.artifacts import seed_metrics_path, table_path
    from lagsplat.report.tables import seed_table

    t = cfg.seed_table
    seeds = [int(s) for s in t.seeds]
    inputs = [seed_metrics_path(cfg.results_dir, str(t.dir), s, cfg.system.name) for s in seeds]
    seed_table(inputs, seeds, table_path(cfg.results_dir, f"{cfg.system.name}_seeds", ".md"))


def stage_krauss_table(cfg: DictConfig) -> None:
    """Paper Table 4 -> ``results/tables/<krauss_table.name>.tex``, ``.csv`` and ``.md``.

    Published rows from the versioned CSV of :mod:`lagsplat.report.krauss`;
    ours from the ``metrics.json`` of ``krauss_table.one_segment`` /
    ``two_segments`` and of the two-segment ``krauss_table.ablation``
    variants. A run whose ``metrics.json`` is missing gives no row.
    """
    from lagsplat.artifacts import table_path, variant_metrics_path
    from lagsplat.report.krauss import krauss_table

    t = cfg.krauss_table
    res = cfg.results_dir
    krauss_table(
        variant_metrics_path(res, str(t.one_segment), None) if t.get("one_segment") else None,
        variant_metrics_path(res, str(t.two_segments), None) if t.get("two_segments") else None,
        [variant_metrics_path(res, str(t.two_segments), str(v)) for v in (t.get("ablation") or [])],
        table_path(res, str(t.name)),
    )


def stage_all(cfg: DictConfig) -> None:
    """Run ingest .. figures for one system in this process."""
    for name in ("ingest", "stage1", "chart", "stage2", "evaluate", "figures"):
        t0 = time.time()
        STAGES[name](cfg)
        print(f"[lagsplat] {cfg.system.name}: {name} done in {time.time() - t0:.1f} s", flush=True)


def stage_view(cfg: DictConfig) -> None:
    """Serve the interactive viewer of the system's artifacts on ``http://127.0.0.1:<view.port>/``.

    Reads ``stage1.pt``, ``chart.npz`` and ``stage2.pt`` (of the variant when
    ``variant`` is set); writes nothing. Runs until Ctrl-C or ``view.max_seconds``.
    """
    from lagsplat.viewer.server import Viewer
    from lagsplat.viewer.session import load_session

    v = cfg.view
    fs = v.get("force_scale", "auto")
    session = load_session(
        artifacts_of(cfg),
        sigma=float(v.sigma),
        force_scale="auto" if fs in (None, "auto") else float(fs),
        kappa=float(v.kappa),
        initial=str(v.initial),
        render_scale=float(v.render_scale),
        max_substeps=int(v.max_substeps),
    )
    viewer = Viewer(session, host="127.0.0.1", port=int(v.port), image_format=str(v.image_format))

    def ready(url: str) -> None:
        print(f"lagsplat view: {cfg.system.name} at {url}  ({session.width}x{session.height} px, dt = {session.dt * 1e3:.1f} ms; Ctrl-C stops)", flush=True)
        if bool(v.open_browser):
            import webbrowser

            webbrowser.open(url)

    max_s = v.get("max_seconds")
    viewer.serve(max_seconds=None if max_s is None else float(max_s), on_ready=ready)


STAGES: dict[str, Callable[[DictConfig], None]] = {
    "download": stage_download,
    "ingest": stage_ingest,
    "stage1": stage_stage1,
    "chart": stage_chart,
    "stage2": stage_stage2,
    "evaluate": stage_evaluate,
    "figures": stage_figures,
    "forces": stage_forces,
    "diagnose": stage_diagnose,
    "table": stage_table,
    "ablation": stage_ablation,
    "krauss_table": stage_krauss_table,
    "seed_table": stage_seed_table,
    "all": stage_all,
    "view": stage_view,
}


def data_kind(system: DictConfig) -> str:
    """What a system's clip is: ``system.data`` when set (``real`` | ``surrogate``), else ``synthetic`` for a
    procedural source (``source.synth``) and ``real`` for a recording."""
    if system.get("data"):
        return str(system.data)
    sources = list(system.get("sources") or []) or [system.get("source") or {}]
    return "synthetic" if all(src.get("synth") for src in sources) else "real"


def stage_help(stage: str) -> str:
    """The help of one stage: its usage line, its entry in :data:`USAGE` and its docstring."""
    lines = USAGE.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(f"  {stage} "))
    end = start + 1
    while end < len(lines) and lines[end].startswith("             "):
        end += 1
    entry = lines[start:end]
    doc = inspect.cleandoc(STAGES[stage].__doc__ or "")
    return (
        f"usage: python -m lagsplat {stage} system=<name> [key=value ...]\n\n"
        + "\n".join(entry) + "\n\n" + doc + "\n\n"
        "Every key of conf/config.yaml and conf/system/<name>.yaml can be set as key=value (Hydra overrides)."
    )


class _Tee:
    """A text stream that writes to the terminal stream and to a log file."""

    def __init__(self, stream, log) -> None:
        self.stream, self.log = stream, log

    def write(self, text: str) -> int:
        self.log.write(text)
        self.log.flush()
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()
        self.log.flush()

    def isatty(self) -> bool:
        return self.stream.isatty()

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


def run_logged(stage: str, cfg: DictConfig) -> None:
    """Run ``STAGES[stage](cfg)``; with ``cfg.log`` set, its stdout and stderr also go to that file (created, truncated)."""
    log_path = cfg.get("log")
    if not log_path:
        STAGES[stage](cfg)
        return
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "w", encoding="utf-8") as log:
        log.write(f"lagsplat {stage} system={cfg.system.name}: started {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        out, err = sys.stdout, sys.stderr
        sys.stdout, sys.stderr = _Tee(out, log), _Tee(err, log)
        t0 = time.perf_counter()
        try:
            STAGES[stage](cfg)
        except BaseException as exc:
            log.write(f"lagsplat {stage}: {type(exc).__name__}: {exc}\n")
            raise
        finally:
            sys.stdout, sys.stderr = out, err
        log.write(f"lagsplat {stage} system={cfg.system.name}: done in {time.perf_counter() - t0:.1f} s\n")


def main(argv: list[str] | None = None) -> int:
    """Entry point. Returns the process exit code (0 ok, 1 error, 2 usage)."""
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(USAGE)
        return 0 if argv else 2
    stage, overrides = argv[0], argv[1:]
    if stage not in STAGES:
        print(f"lagsplat: unknown stage {stage!r}\n\n{USAGE}", file=sys.stderr)
        return 2
    if any(a in ("-h", "--help") for a in overrides):
        print(stage_help(stage))
        return 0
    from lagsplat.io.clip import ClipError
    from lagsplat.io.download import DownloadError

    try:
        from lagsplat.config_check import ConfigError, validate_config

        cfg = compose(overrides)
        try:
            validate_config(cfg)  # a bad value stops here, before any work, naming key and value
        except ConfigError as exc:
            print(f"lagsplat {stage}: configuration error: {exc}", file=sys.stderr)
            return 1
        cfg = apply_variant(cfg)  # its settings were checked with the variants
        if "device" in cfg:  # a bad or unavailable device fails here, before any work
            from lagsplat.train.device import resolve_device

            resolve_device(str(cfg.device))
        if int(cfg.threads) > 0:
            import torch

            torch.set_num_threads(int(cfg.threads))
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Converting a tensor with requires_grad=True to a scalar")
            run_logged(stage, cfg)
    except (ClipError, DownloadError, FileNotFoundError, KeyError, ValueError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        print(f"lagsplat {stage}: error: {msg}", file=sys.stderr)
        return 1
    except Exception as exc:  # hydra config errors etc.
        if type(exc).__module__.startswith(("hydra", "omegaconf")):
            from lagsplat.config_check import explain_compose_error

            print(f"lagsplat {stage}: configuration error: {explain_compose_error(exc, overrides, find_conf_dir())}", file=sys.stderr)
            return 1
        raise
    return 0

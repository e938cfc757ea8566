"""The pipeline stages of the command line, one per Snakemake rule: download, ingest, views (3-D systems), stage1, chart,
stage2, evaluate, figures.

Each reads only upstream artifacts under ``${results_dir}/${system.name}/``
(:class:`lagsplat.artifacts.Artifacts`) and writes its own atomically, with
the resolved configuration saved beside it (``config/<stage>.yaml``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig, open_dict

from lagsplat.cli_common import artifacts_of, data_kind, plain, save_stage_config

if TYPE_CHECKING:
    from lagsplat.artifacts import Artifacts

__all__ = ["stage_download", "stage_ingest", "stage_views", "stage_stage1", "stage_chart", "stage_stage2", "stage_evaluate", "stage_figures"]


def stage_download(cfg: DictConfig) -> None:
    """Fetch the source clip(s) to ``source.path`` and verify their SHA256.

    With ``sources`` (several recordings) every entry with a ``url`` is
    fetched, or only the one whose ``file`` is ``download.file`` when set.
    ``artifacts.source`` (one file to fetch) writes it there instead of ``source.path``.
    """
    from lagsplat.io.download import fetch

    entries = list(cfg.system.get("sources") or []) or [cfg.system.source]
    dl = cfg.get("download") or {}
    only = dl.get("file")
    todo = [e for e in entries if e.get("url") and (not only or e.get("file") == only)]
    if not todo:
        print(f"{cfg.system.name}: nothing to download (no source.url)")
        return
    given = artifacts_of(cfg).source
    if given is not None and len(todo) > 1:
        raise ValueError(f"artifacts.source={given}: {len(todo)} source files to download; choose one with download.file")
    for src in todo:
        path = Path(given) if given is not None else Path(src.path)
        if src.get("member"):  # a file inside a zip archive (lagsplat.io.zenodo): the member's SHA256 is verified
            from lagsplat.io.zenodo import fetch_member

            cache = Path(cfg.raw_dir) / src.archive_file if src.get("archive_file") else None
            hint = "or give a local copy with download.archive=PATH (Snakemake: --config krauss_archive=PATH)"
            fetch_member(src.url, src.member, path, src.sha256, archive=dl.get("archive"), cache=cache, hint=hint)
            continue
        fetch(src.url, path, src.sha256)


def stage_ingest(cfg: DictConfig) -> None:
    """Source clip (``artifacts.source`` when given, else ``system.source.path``) -> ``clip.npz``."""
    from lagsplat.config_schema import SystemConfig
    from lagsplat.ingest import ingest_to_file

    system = plain(cfg.system)
    for key in ("crop", "resize"):  # absent: the schema's default (auto: read off the motion)
        system.setdefault(key, getattr(SystemConfig, key))
    if "train_fraction" not in (system.get("split") or {}) and "path" in (system.get("source") or {}):
        system["split"] = {**(system.get("split") or {}), "train_fraction": "auto"}  # a recording: three periods held out
    a = artifacts_of(cfg)
    ingest_to_file(system, a.clip, source_path=a.source, preview=a.prepare_preview if "path" in (system.get("source") or {}) else None)
    clip = a.load_clip()
    prepared = clip.meta.get("prepare")
    if prepared:  # the automatic choices, printed and written into the resolved configuration
        from lagsplat.prepare import Preparation

        print(f"[lagsplat] {cfg.system.name}: prepared {Preparation(**prepared).summary()} (drawn in {a.prepare_preview})", flush=True)
        if clip.no_held_out:
            print(f"[lagsplat] {cfg.system.name}: too short for the held-out protocol: identified on all its frames, {clip.no_held_out}", flush=True)
        with open_dict(cfg):
            cfg.system.crop, cfg.system.resize = clip.meta["crop"], clip.meta["resize"]
            cfg.system.split = {**plain(cfg.system.get("split") or {}), "train_fraction": clip.meta["split"]["train_fraction"]}
    save_stage_config(cfg, "ingest")


def view_settings(cfg: DictConfig) -> dict:
    """``system.views`` without its unset keys (the settings the views' cache key reads); empty for a 2-D system."""
    return {k: v for k, v in plain(cfg.system.get("views") or {}).items() if v is not None}


def stage_views(cfg: DictConfig, a: "Artifacts | None" = None) -> None:
    """``clip.npz`` -> ``views/``: a 3-D system's cached novel views of every frame and their cameras
    (``system.views``; :mod:`lagsplat.views`), recomputed only when the clip or the view settings change."""
    from lagsplat.views import ensure_views

    a = a or artifacts_of(cfg)
    settings = view_settings(cfg)
    if not settings:
        raise ValueError(f"system {cfg.system.name!r} has no views (system.views): only a 3-D system caches novel views")
    views, computed = ensure_views(a.views, a.load_clip(), settings)
    held = f", held out {views.holdout}" if views.holdout else ""
    print(f"[lagsplat] {cfg.system.name}: {views.n_views} views of {len(views.images)} frames ({settings['source']}{held}), "
          + ("computed" if computed else "cached, unchanged"), flush=True)  # fmt: skip
    save_stage_config(cfg, "views", a)


def stage_stage1(cfg: DictConfig, a: "Artifacts | None" = None) -> None:
    """``clip.npz`` -> ``stage1.pt`` (paths: ``a``, default the run's :func:`~lagsplat.cli_common.artifacts_of`)."""
    from lagsplat.models.autoencoder import save_stage1
    from lagsplat.train.attempts import train_stage1_gated
    from lagsplat.train.stage1 import Stage1Config

    a = a or artifacts_of(cfg)
    clip = a.load_clip()
    s1 = Stage1Config.from_mapping(plain(cfg.stage1))
    views = a.load_views() if s1.decoder == "conditioned3d" else None
    chart_kw = {"n_metric_samples": int(cfg.chart.n_metric_samples), "rho": float(cfg.chart.rho), "refine_iters": int(cfg.chart.refine_iters)}
    model, hist, attempts = train_stage1_gated(
        clip, s1, int(cfg.system.d), seed=int(cfg.seed), retries=s1.retries if bool(cfg.chart.gate) else 0, chart_kwargs=chart_kw,
        progress=bool(cfg.progress), device=str(cfg.device), label=f"{cfg.system.name} stage1", views=views,
    )  # fmt: skip
    hist["attempts"] = attempts
    save_stage1(a.stage1, model, plain(cfg.stage1), hist, int(cfg.system.d))
    save_stage_config(cfg, "stage1", a)


def stage_chart(cfg: DictConfig, a: "Artifacts | None" = None) -> None:
    """``stage1.pt`` -> ``chart.npz`` (paths: ``a``, default the run's :func:`~lagsplat.cli_common.artifacts_of`): the gated
    chart (:func:`lagsplat.chart.gate.gated_chart`), read from the checkpoint where Stage 1 built it for the same clip and
    chart settings (:func:`lagsplat.chart.gate.chart_from_record`), built otherwise."""
    from lagsplat.chart import save_chart

    from lagsplat.chart.gate import chart_from_record, chart_key, gate_summary, gated_chart

    a = a or artifacts_of(cfg)
    clip = a.load_clip()
    kw = {"n_metric_samples": int(cfg.chart.n_metric_samples), "rho": float(cfg.chart.rho), "seed": int(cfg.seed), "refine_iters": int(cfg.chart.refine_iters)}
    kept = chart_from_record(a.load_stage1_history().get("gated_chart"), chart_key(clip, **kw))  # Stage 1 built it to gate its attempt
    chart, gate = kept if kept is not None else gated_chart(a.load_stage1(), clip, **kw)
    chart.meta["gate"] = gate
    if "refine_choice" in chart.meta:
        print(f"[lagsplat] {cfg.system.name}: chart {chart.meta['refine_choice']['reason']}", flush=True)
    print(f"[lagsplat] {cfg.system.name}: chart quality gate {gate_summary(chart.meta['gate'])}", flush=True)
    save_chart(a.chart, chart)
    save_stage_config(cfg, "chart", a)


def stage_stage2(cfg: DictConfig, a: "Artifacts | None" = None) -> None:
    """``chart.npz`` -> ``stage2.pt`` (paths: ``a``, default the run's :func:`~lagsplat.cli_common.artifacts_of`)."""
    from lagsplat.train.stage2 import Stage2Config, save_stage2, train_stage2

    from lagsplat.chart.gate import gate_summary

    a = a or artifacts_of(cfg)
    s2 = Stage2Config.from_mapping(plain(cfg.stage2))
    chart = a.load_chart()
    gate = chart.meta.get("gate")
    if gate is not None and not gate["passed"] and bool(cfg.chart.gate):
        raise ValueError(f"{a.chart}: the chart {gate_summary(gate)}; Stage 2 not run (chart.gate=false runs it, its metrics marked)")
    inertia = None
    if s2.mass == "decoder":  # parameter-free inertia from the frozen Stage-1 decoder (paper Eq. 7)
        from lagsplat.models.inertia import DecoderInertia

        ae = a.load_stage1()
        inertia = DecoderInertia.from_decoder(ae.decoder, chart.W_inv, chart.mean, chart.height, chart.width)
    # a clip identified on all its frames: its selection rollouts start at several phases, over at most half of it
    share = 0.5 if a.load_clip().no_held_out is not None else 1.0
    model, hist = train_stage2(
        chart, s2, seed=int(cfg.seed), progress=bool(cfg.progress), inertia=inertia, device=str(cfg.device), label=f"{cfg.system.name} stage2",
        select_share=share,
    )  # fmt: skip
    save_stage2(a.stage2, model, s2, hist)
    save_stage_config(cfg, "stage2", a)


def stage_evaluate(cfg: DictConfig) -> None:
    """Upstream artifacts -> ``metrics.json``; a clip without held-out frames (``Clip.no_held_out``) is read in-sample,
    its note in ``metrics.json``'s ``held_out`` (:mod:`lagsplat.evaluate.in_sample`)."""
    from lagsplat.evaluate import SETTINGS_GROUP, protocol_for, run_protocol
    from lagsplat.io.atomic import write_json

    a = artifacts_of(cfg)
    clip, chart = a.load_clip(), a.load_chart()
    model, ck = a.load_stage2()
    protocol = protocol_for(cfg.system)  # the published soft-robot protocol for system.protocol=krauss (paper §4.4, Table 4)
    settings = cfg.get(SETTINGS_GROUP[protocol])
    ae = a.load_stage1()
    m = run_protocol(protocol, clip, ae, chart, model, plain(settings) if settings else {}, plain(cfg.system), str(a.clip))
    if ae.decoder.n_space == 3:  # a 3-D model: its novel viewpoints too (paper §3.2, App. C)
        from lagsplat.evaluate.views import view_metrics

        m.update(view_metrics(ae, clip, a.load_views()))
    if protocol in ("paper", "default"):  # the identified frequency's and damping ratio's calibrated intervals
        from lagsplat.evaluate.intervals import intervals, load_calibration

        m.update(intervals(m, load_calibration()))
    gate = chart.meta.get("gate")
    if gate is not None and not gate["passed"]:  # run with chart.gate=false: every number says what it stands on
        from lagsplat.chart.gate import gate_summary

        for entry in m.values():
            if isinstance(entry, dict):
                entry["caution"] = f"read on a chart that {gate_summary(gate)}"
    doc = {}
    if clip.no_held_out is not None:  # identified on all its frames: the held-out metrics are null, the in-sample ones say what they can
        doc["held_out"] = clip.no_held_out
    write_json(
        a.metrics,
        {
            **doc,
            "system": cfg.system.name,
            "variant": cfg.get("variant"),
            "protocol": protocol,
            "data": data_kind(cfg.system),
            "stage2": plain(cfg.stage2),
            "title": cfg.system.get("title", cfg.system.name),
            "d": int(cfg.system.d),
            "provenance": cfg.system.get("provenance", ""),
            "dt_s": float(clip.dt),
            "n_train": int(len(clip.train_idx)),
            "n_held_out": int(len(clip.held_out_idx)),
            "image_size": [chart.width, chart.height],
            "stage2_selected_epoch": ck["history"].get("selected_epoch"),
            "chart_gate": chart.meta.get("gate"),
            "read_on_failed_chart": not chart.meta["gate"]["passed"] if "gate" in chart.meta else None,
            "metrics": m,
        },
    )
    save_stage_config(cfg, "evaluate")


def stage_figures(cfg: DictConfig) -> None:
    """Upstream artifacts -> ``figures/rollout.png``."""
    from lagsplat.viz.rollout import rollout_figure

    title = str(cfg.system.get("title", cfg.system.name)) + (f" [{cfg.variant}]" if cfg.get("variant") else "")
    rollout_figure(artifacts_of(cfg), title=title, provenance=str(cfg.system.get("provenance", "")))

"""The stages of the command line after the pipeline: forces, diagnosis, tables, the viewer.

Each reads the artifacts of the pipeline stages (:mod:`lagsplat.stages`) and
writes its own atomically, with the resolved configuration saved beside it.
"""

from __future__ import annotations


from omegaconf import DictConfig, OmegaConf

from lagsplat.cli_common import artifacts_of, plain, save_stage_config

__all__ = ["stage_forces", "stage_export", "stage_diagnose", "stage_table", "stage_ablation", "stage_seed_table", "stage_views_table", "stage_krauss_table", "stage_render", "stage_view"]


def stage_forces(cfg: DictConfig) -> None:
    """Force-transport checks (paper §3.4, Fig. 7) -> ``forces.json`` and ``figures/forces.png``.

    The figure and the top level of ``forces.json`` use the default brush
    (``brush``); ``other_brushes`` holds the background, linearity and kernel
    checks through the others (:data:`lagsplat.forces.transport.BRUSHES`).
    """
    import numpy as np
    import torch

    from lagsplat.forces.transport import BRUSHES, ForceTransport
    from lagsplat.forces.checks import ForceCheckConfig, plot_force_checks, public_result, run_force_checks
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
        from lagsplat.forces.checks import lever_profile
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
    # the same checks through the other brush (lagsplat.forces.transport.BRUSHES), for comparison
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


def stage_export(cfg: DictConfig) -> None:
    """The identified model for use outside lagsplat -> ``export/`` (docs/export.md): ``dynamics.py`` (NumPy,
    ``rhs(t, [q, qdot], u=None)`` for ``scipy.integrate.solve_ivp``) with ``weights.npz``, TorchScript ``M.pt``,
    ``V.pt``, ``C.pt`` (``b.pt`` with inputs), ``model.json``, ``trajectory.csv``, ``rollout.csv`` and the decoder
    at the chart's mean, min and max per coordinate as 3DGS ``splat_q_<k>.ply`` files.

    Reads ``clip.npz``, ``stage1.pt``, ``chart.npz``, ``stage2.pt`` and, if present, ``metrics.json`` (of the
    variant when ``variant`` is set). A model outside the compiled rollout path (``stage2.mass=decoder``) or a
    decoder without conditioned Gaussians (the deformation decoder) stops with the reason, writing nothing.
    """
    from lagsplat.export import export_run

    a = artifacts_of(cfg)
    source = (cfg.system.get("source") or {}).get("path") if cfg.get("system") else None
    written = export_run(a, provenance={"system": str(cfg.system.name), "variant": cfg.get("variant"), "source_path": source})
    sizes = sum(p.stat().st_size for p in written.values())
    print(f"[lagsplat] {cfg.system.name}: exported {len(written)} files ({sizes / 1e6:.2f} MB) to {a.export}", flush=True)
    save_stage_config(cfg, "export", a)


def stage_diagnose(cfg: DictConfig) -> None:
    """Sim-to-real gap diagnosis -> ``diagnosis/report.md``, ``report.json``, ``figures/*.png``.

    Reads ``clip.npz``, ``stage1.pt``, ``chart.npz``, ``stage2.pt`` and
    ``metrics.json`` (of the variant when ``variant`` is set); settings in the
    ``diagnose`` group, the gap protocol in ``evaluate``; the refit uses the
    Stage-2 settings saved in ``stage2.pt``. See :mod:`lagsplat.diagnose.report`.

    When an earlier stage stopped (its ``stopped.json``: ingest refused the clip,
    Stage 2 refused a chart that failed the quality gate), the report has the
    verdict ``cannot_diagnose`` with that stage's reason, and the stage exits 0:
    a report written is the diagnose stage's success, so a batch scores every clip.
    """
    from lagsplat.diagnose.report import DiagnoseConfig, diagnose_system
    from lagsplat.evaluate import EvalConfig

    dc = DiagnoseConfig.from_mapping(plain(cfg.diagnose) if cfg.get("diagnose") else None)
    dc.refit.seed = int(cfg.seed)
    title = str(cfg.system.get("title", cfg.system.name)) + (f" [{cfg.variant}]" if cfg.get("variant") else "")
    a = artifacts_of(cfg)
    rep = diagnose_system(a, dc, EvalConfig(**plain(cfg.evaluate)), title, bool(cfg.progress), plain(cfg.system.scale) if cfg.system.get("scale") else None)
    gap = rep.get("gap") or {}  # none when the run stopped at the chart-quality gate
    red = (gap.get("reduction") or {}).get("eps_q")
    print(
        f"{cfg.system.name}: {rep['verdict_text']}"
        + (f"; held-out eps_q {gap['before']['eps_q']:.4f}" if gap.get("before") else "")
        + (f" -> {gap['after']['eps_q']:.4f} ({100 * red:+.0f} %)" if red is not None else "")
        + (f"; {rep['held_out']}, held-out refit validation skipped" if rep.get("held_out") else "")
        + f"; report: {a.report_md}"
    )
    from lagsplat.io.atomic import atomic_write

    with atomic_write(a.diagnosis_config) as tmp:  # beside the report: the stage writes only under diagnosis/
        tmp.write_text(OmegaConf.to_yaml(cfg, resolve=True))


def stage_table(cfg: DictConfig) -> None:
    """``metrics.json`` of ``table.systems`` -> ``results/tables/<table.name>.tex`` and ``.csv``
    (paths: ``artifacts.table_inputs``, ``table_tex``, ``table_csv`` when given)."""
    from lagsplat.artifacts import variant_metrics_path
    from lagsplat.report.tables import physical_table

    t = cfg.get("table", {})
    name = t.get("name", "physical")
    systems = list(t.get("systems", [cfg.system.name]))
    a, res = artifacts_of(cfg), cfg.results_dir
    inputs = a.table_sources([variant_metrics_path(res, s, None) for s in systems])
    physical_table(inputs, a.table(res, name), a.table(res, name, ".csv"))


def stage_ablation(cfg: DictConfig) -> None:
    """Variant ``metrics.json`` of one system -> ``results/tables/<system>_<ablation>.tex`` and ``.csv``
    (with ``ablation_seeds``: each variant's runs ``<variant>@seed<k>``, its row the median over them; paths:
    ``artifacts.table_inputs``, ``table_tex``, ``table_csv`` when given)."""
    from lagsplat.artifacts import variant_metrics_path
    from lagsplat.cli_common import seeded_variants
    from lagsplat.report.tables import ablation_table

    key = str(cfg.ablation)
    if key not in cfg.ablations:
        raise KeyError(f"unknown ablation {key!r}; known: {sorted(cfg.ablations)} (conf/config.yaml, key ablations)")
    seeds = cfg.get("ablation_seeds")
    a, res, name = artifacts_of(cfg), cfg.results_dir, f"{cfg.system.name}_{key}"
    inputs = a.table_sources([[variant_metrics_path(res, cfg.system.name, r) for r in seeded_variants(v, seeds)] for v in cfg.ablations[key]])
    ablation_table(inputs, a.table(res, name), a.table(res, name, ".csv"))


def stage_seed_table(cfg: DictConfig) -> None:
    """One system trained with each of ``seed_table.seeds`` -> ``results/tables/<system>_seeds.md`` and ``.csv``.

    Reads ``${results_dir}/${seed_table.dir}/seed<k>/<system>/metrics.json``:
    the ``evaluate`` output of a run with ``seed=<k>
    results_dir=${results_dir}/${seed_table.dir}/seed<k>`` (the Snakemake
    rule ``seed_run``). Paths: ``artifacts.table_inputs``, ``table_md``, ``table_csv`` when given.
    """
    from lagsplat.artifacts import seed_metrics_path
    from lagsplat.report.tables import seed_table

    t = cfg.seed_table
    seeds = [int(s) for s in t.seeds]
    a, res, name = artifacts_of(cfg), cfg.results_dir, f"{cfg.system.name}_seeds"
    inputs = a.table_sources([seed_metrics_path(res, str(t.dir), s, cfg.system.name) for s in seeds])
    seed_table(inputs, seeds, a.table(res, name, ".md"), a.table(res, name, ".csv"))


def stage_views_table(cfg: DictConfig) -> None:
    """A 3-D model's PSNR on its training views and on the held-out cameras (paper §3.2 and App. C), one row per system of
    ``table.systems`` -> ``results/tables/<table.name>.csv`` and ``.md`` (paths: ``artifacts.table_inputs``,
    ``table_csv``, ``table_md`` when given)."""
    from lagsplat.artifacts import variant_metrics_path
    from lagsplat.report.tables import view_table

    t = cfg.get("table", {})
    name = t.get("name", "novel_views")
    systems = list(t.get("systems", [cfg.system.name]))
    a, res = artifacts_of(cfg), cfg.results_dir
    inputs = a.table_sources([variant_metrics_path(res, s, None) for s in systems])
    view_table(inputs, a.table(res, name, ".csv"), a.table(res, name, ".md"))


def stage_krauss_table(cfg: DictConfig) -> None:
    """Paper Table 4 -> ``results/tables/<krauss_table.name>.tex``, ``.csv`` and ``.md``.

    Published rows from the versioned CSV of :mod:`lagsplat.report.krauss`;
    ours from the ``metrics.json`` of ``krauss_table.one_segment`` /
    ``two_segments`` and of the two-segment ``krauss_table.ablation``
    variants (with ``ablation_seeds``: each variant's seeded runs, its row the
    median). A run whose ``metrics.json`` is missing gives no row. Paths: ``artifacts.table_inputs`` (one
    segment, two segments, then the ablation's runs), ``table_tex``, ``table_csv``, ``table_md`` when given.
    """
    from lagsplat.artifacts import variant_metrics_path
    from lagsplat.cli_common import seeded_variants
    from lagsplat.report.krauss import krauss_table

    t = cfg.krauss_table
    a, res, name = artifacts_of(cfg), cfg.results_dir, str(t.name)
    seeds = cfg.get("ablation_seeds")
    one, two, ablation = a.table_sources([
        variant_metrics_path(res, str(t.one_segment), None) if t.get("one_segment") else None,
        variant_metrics_path(res, str(t.two_segments), None) if t.get("two_segments") else None,
        [[variant_metrics_path(res, str(t.two_segments), r) for r in seeded_variants(str(v), seeds)] for v in (t.get("ablation") or [])],
    ])  # fmt: skip
    krauss_table(one, two, ablation, a.table(res, name), out_csv=a.table(res, name, ".csv"), out_md=a.table(res, name, ".md"))


def stage_robot_figures(cfg: DictConfig) -> None:
    """Upstream artifacts -> ``figures/robot_rollout.png`` (a long pressure-driven rollout decoded at high
    resolution, paper Fig. krauss-npz-rollout) and ``figures/robot_forces.png`` (loaded equilibria
    at the operating pressure, Fig. krauss-force; panels from ``system.segments``), its record ``robot_forces.json``."""
    from lagsplat.config_schema import RobotFigureConfig
    from lagsplat.train.config import dataclass_from_mapping
    from lagsplat.viz.robot import robot_force_figure, robot_rollout_figure

    a = artifacts_of(cfg)
    rc = dataclass_from_mapping(RobotFigureConfig, plain(cfg.get("robot_figures", {})), "robot_figures")
    title = str(cfg.system.get("title", cfg.system.name)) + (f" [{cfg.variant}]" if cfg.get("variant") else "")
    r = robot_rollout_figure(a, a.robot_rollout_figure, rc.rollout_s, rc.size, rc.sigma, title, str(cfg.system.get("provenance", "")))
    print(f"[lagsplat] {cfg.system.name}: {r['seconds']:.1f} s of free rollout, offset at the last step {r['offset_px']:.2f} px -> {r['figure']}")
    f = robot_force_figure(a, a.robot_forces_figure, a.robot_forces, int(cfg.system.get("segments", 1) or 1), rc.size, rc.brush_sigma, rc.displacement, title)
    print(f"[lagsplat] {cfg.system.name}: {len(f['panels'])} loaded equilibria at pressure {f['pressure']} -> {f['figure']}")


def stage_render(cfg: DictConfig) -> None:
    """A 3-D model's novel views (``render`` group) -> ``figures/novel_views.mp4`` and ``figures/novel_views.png``:
    the encoded state of one frame (or a free Stage-2 rollout from it) seen from an orbit (there and back across the
    azimuths the cameras filmed from, at the main camera's distance and elevation) or from cameras in a JSON."""
    import numpy as np
    import torch

    from lagsplat.dynamics.integrators import initial_state, rollout
    from lagsplat.render.camera import load_cameras, orbit_through
    from lagsplat.viz.novel_views import novel_view_frames, write_novel_views

    a, r = artifacts_of(cfg), cfg.render
    ae, chart, clip = a.load_stage1(), a.load_chart(), a.load_clip()
    if ae.decoder.n_space != 3:
        raise ValueError(f"{a.stage1}: a 2-D model has no novel views (render needs stage1.decoder=conditioned3d)")
    W, H = (int(v) for v in r.size) if r.get("size") else (2 * ae.width, 2 * ae.height)
    if str(r.camera) == "orbit":
        from lagsplat.views import scene_center

        views = a.load_views()
        cams = orbit_through(ae.decoder.camera, scene_center(views.cameras), int(r.n_cameras), W, H, span=views.cameras[1:])
    else:
        cams = [c.resized(W, H) for c in load_cameras(str(r.camera))]
    frame = int(r.frame) if r.get("frame") is not None else int(clip.held_out_idx[0] if len(clip.held_out_idx) else 0)
    if not 0 <= frame < len(chart.q) - 2:
        raise ValueError(f"render.frame={frame} outside the clip's {len(chart.q)} frames (need two after it)")
    q = chart.q[frame : frame + 1]
    if float(r.rollout_s) > 0:
        model, _ = a.load_stage2()
        q0, v0 = initial_state(chart.q, np.array([frame]), clip.dt)
        q = rollout(model, q0, v0, clip.dt, max(2, int(round(float(r.rollout_s) / clip.dt))))[0][0].numpy()
        cams = [cams[k % len(cams)] for k in range(len(q))]
    z = chart.to_raw(torch.as_tensor(q, dtype=torch.float32))
    frames = novel_view_frames(ae.decoder, z, cams, H, W)
    what = f"{float(r.rollout_s):g} s rollout from frame {frame}" if float(r.rollout_s) > 0 else f"frame {frame}"
    video, sheet = write_novel_views(frames, a.novel_views_video, a.novel_views_figure, float(r.fps), f"{cfg.system.name}: {what}, {len(cams)} views")
    print(f"[lagsplat] {cfg.system.name}: novel views -> {video}, {sheet}", flush=True)


def stage_view(cfg: DictConfig) -> None:
    """Serve the interactive viewer of the system's artifacts on ``http://127.0.0.1:<view.port>/``.

    Reads ``stage1.pt``, ``chart.npz`` and ``stage2.pt`` (of the variant when
    ``variant`` is set); writes nothing. Runs until Ctrl-C or ``view.max_seconds``.
    A 3-D model opens the viser viewer instead (:mod:`lagsplat.viewer.viewer3d`): orbit it, click to push it
    along the line of sight (``view.force_3d`` world units, ``auto`` by default).
    """
    from lagsplat.viewer.server import Viewer
    from lagsplat.viewer.session import Session

    v = cfg.view
    a = artifacts_of(cfg)
    a.require("stage1", "chart", "stage2")
    ae, chart, model = a.load_stage1(), a.load_chart(), a.load_stage2()[0]
    if ae.decoder.n_space == 3:
        from lagsplat.viewer.viewer3d import Session3D, serve_viser

        s3 = Session3D(ae, chart, model, force=v.get("force_3d", "auto"), kappa=float(v.kappa))
        max_s = v.get("max_seconds")
        serve_viser(s3, int(v.port), None if max_s is None else float(max_s), render=str(v.get("render_3d", "browser")),
                    size=max(1, round(ae.decoder.camera.height * float(v.render_scale))),
                    on_ready=lambda url: print(f"lagsplat view: {cfg.system.name} (3-D) at {url}  (push {s3.force:.3g} world units; Ctrl-C stops)", flush=True))  # fmt: skip
        return
    fs = v.get("force_scale", "auto")
    session = Session(
        ae,
        chart,
        model,
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

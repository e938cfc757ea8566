"""The stages of the command line that weigh the prior against baselines: extrapolation and its table (paper §4.3, Table 3).

Each reads the pipeline's artifacts (:mod:`lagsplat.stages`) and writes its own atomically, with the
resolved configuration saved beside it.
"""

from __future__ import annotations

import time

from omegaconf import DictConfig

from lagsplat.cli_common import artifacts_of, plain, save_stage_config

__all__ = ["stage_extrapolation", "stage_extrapolation_table"]


def stage_extrapolation(cfg: DictConfig) -> None:
    """LaGSplat, the latent neural ODE and GP-2D, trained on the training frames, predicting the rest and 1000 s past it -> ``extrapolation.json`` and ``figures/extrapolation.png`` (paper Fig. 5 layout).

    Reads ``clip.npz``, ``stage1.pt``, ``chart.npz`` and ``stage2.pt``. The neural ODE
    (:mod:`lagsplat.baselines.neural_ode`) is trained here on the same frozen chart with the Stage-2
    settings saved in ``stage2.pt`` (same windows, loss, budget and selection); both are scored by
    :func:`lagsplat.baselines.extrapolation.extrapolation_metrics` (settings: the ``extrapolation`` group).
    GP-2D (:mod:`lagsplat.baselines.gp2d`, the ``gp2d`` group) and, when ``extrapolation.gaussian_prediction_frames``
    names a folder, the original GaussianPrediction's frames are read through the frozen encoder and scored by
    :func:`lagsplat.baselines.extrapolation.frame_extrapolation_metrics`.
    """
    import numpy as np
    import torch

    from lagsplat.baselines import ode_rollout, train_neural_ode
    from lagsplat.baselines.extrapolation import ExtrapolationConfig, extrapolation_metrics, protocol_windows, real_trace
    from lagsplat.dynamics.integrators import rollout
    from lagsplat.io.atomic import write_json
    from lagsplat.train.config import dataclass_from_mapping
    from lagsplat.train.stage2 import Stage2Config
    from lagsplat.viz.extrapolation import extrapolation_figure

    xc = dataclass_from_mapping(ExtrapolationConfig, plain(cfg.get("extrapolation") or {}), "extrapolation")
    a = artifacts_of(cfg)
    clip, ae, chart = a.load_clip(), a.load_stage1(), a.load_chart()
    model, saved = a.load_stage2()
    model.eval()
    s2 = Stage2Config.from_mapping(saved.get("config") or {})
    t0 = time.perf_counter()
    node, hist = train_neural_ode(chart, s2, seed=int(cfg.seed))
    node_s = time.perf_counter() - t0
    as_t = lambda x: torch.as_tensor(np.asarray(x)[None], dtype=torch.float32)  # noqa: E731

    def lagsplat_predictor(q0, v0, dt, n):
        return rollout(model, as_t(q0), as_t(v0), dt, n)[0][0].numpy()

    def neural_ode_predictor(q0, v0, dt, n):
        return ode_rollout(node, as_t(q0), as_t(v0), dt, n)[0].numpy()

    models = {}
    for name, pred in (("lagsplat", lagsplat_predictor), ("neural_ode", neural_ode_predictor)):
        models[name] = extrapolation_metrics(chart, pred, xc.long_s, xc.sigma, ae, clip.images, xc.render_batch, xc.figure_s)
    models["neural_ode"].update(train_s=node_s, selected_train_nrmse=hist["selected_nrmse"])
    names = {"lagsplat": "LaGSplat", "neural_ode": "latent neural ODE"}
    w = protocol_windows(chart, xc.long_s, xc.sigma, xc.figure_s)
    if xc.gp2d:
        models["gp2d"], names["gp2d"] = _gp2d_row(cfg, chart, ae, clip.images, w, xc), "GP-2D"
    if xc.gaussian_prediction_frames:
        models["gaussian_prediction"], names["gaussian_prediction"] = _imported_row(xc.gaussian_prediction_frames, chart, ae, clip.images, w, xc), "GaussianPrediction"
    rec = {"system": str(cfg.system.name), "title": str(cfg.system.get("title", cfg.system.name)), "models": models,
           "names": names, "real": real_trace(w, chart), "config": plain(cfg.get("extrapolation") or {}), "gp2d_config": plain(cfg.get("gp2d") or {})}  # fmt: skip
    write_json(a.extrapolation, rec)
    extrapolation_figure(rec, a.extrapolation_figure)
    save_stage_config(cfg, "extrapolation")
    pct = lambda v, fmt: "--" if v is None else format(100 * v, fmt)  # noqa: E731 (a row a model cannot give)
    for name, m in models.items():
        print(f"{cfg.system.name} {names[name]}: frequency error {pct(m['freq_error'], '.1f')} %, dissipation error {pct(m['dissipation_error'], '.0f')} %, "
              f"amplitude left after {m['long_s']:.0f} s {pct(m['amplitude_left'], '.2f')} %, PSNR {m['psnr_mean']:.2f} dB")  # fmt: skip


def _gp2d_row(cfg: DictConfig, chart, ae, frames, w, xc) -> dict:
    """GP-2D fitted on the training frames before the held-out segment, its predictions scored in the chart."""
    from lagsplat.baselines.extrapolation import frame_extrapolation_metrics
    from lagsplat.baselines.gp2d import gp2d_predictions
    from lagsplat.baselines.gp2d_field import GP2DConfig
    from lagsplat.train.config import dataclass_from_mapping

    gc = dataclass_from_mapping(GP2DConfig, plain(cfg.get("gp2d") or {}), "gp2d")
    t0 = time.perf_counter()
    pred, model, fit = gp2d_predictions(chart, frames, w, gc, seed=int(cfg.seed), log_every=2000)
    row = frame_extrapolation_metrics(chart, ae, frames, w, pred["held_out"], pred["window"], pred["long"], xc.long_s, xc.render_batch, pred["near"])
    h = model.history
    row.update(_fit_psnr(model, chart, ae, frames, fit, xc.render_batch))
    row.update(train_s=time.perf_counter() - t0, field_train_s=h["field"]["train_s"], forecaster_train_s=h["forecaster"]["train_s"],
               n_fitted_frames=len(fit), gp2d_resolved=h["field"]["config"])  # fmt: skip
    return row


def _fit_psnr(model, chart, ae, frames, fit: list[int], batch: int) -> dict:
    """GP-2D's reconstruction of the frames it was fitted on (its fitted key-point states rendered) beside the
    LaGSplat autoencoder floor on the same frames: mean PSNR over frames, dB (notes' "reconstruction floor")."""
    import math

    from lagsplat.baselines.extrapolation import ae_floor_psnr, finite_mean, frames_psnr

    gp = frames_psnr(model.render(model.states), frames[fit])
    return {"psnr_fit_mean": finite_mean(gp, math.nan), "psnr_ae_floor_fit_mean": ae_floor_psnr(ae, chart, frames, fit, batch, math.nan)}


def _imported_row(folder: str, chart, ae, frames, w, xc) -> dict:
    """Frames predicted by the original GaussianPrediction (:mod:`lagsplat.baselines.gp_frames`), scored like GP-2D."""
    from lagsplat.baselines.extrapolation import frame_extrapolation_metrics
    from lagsplat.baselines.gp_frames import load_prediction_frames, prediction_arrays

    pred, _ = load_prediction_frames(folder, float(chart.t[w.ho[0]]), w.dt, frames.shape[1], frames.shape[2])
    ho, long_ends, n = prediction_arrays(pred, len(w.ho), w.m_period)
    row = frame_extrapolation_metrics(chart, ae, frames, w, ho, None, long_ends, (n - 1) * w.dt, xc.render_batch, pred[: w.n_near])
    row.update(source=str(folder), n_predicted_frames=int(len(pred)))
    return row


def stage_extrapolation_table(cfg: DictConfig) -> None:
    """``extrapolation.json`` of ``table.systems`` -> ``results/tables/extrapolation.tex``, ``.csv`` and ``.md`` (paper Table 3
    layout; paths: ``artifacts.table_inputs``, ``table_tex``, ``table_csv``, ``table_md`` when given)."""
    from lagsplat.artifacts import Artifacts
    from lagsplat.report.tables import extrapolation_table

    t = cfg.get("table", {})
    systems = list(t.get("systems", [cfg.system.name]))
    a, res = artifacts_of(cfg), cfg.results_dir
    inputs = a.table_sources([Artifacts.for_run(res, s).extrapolation for s in systems])
    extrapolation_table(inputs, a.table(res, "extrapolation"), a.table(res, "extrapolation", ".csv"), a.table(res, "extrapolation", ".md"))

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
    """LaGSplat and the latent neural ODE, trained on the training frames, predicting the rest and 1000 s past it -> ``extrapolation.json``.

    Reads ``clip.npz``, ``stage1.pt``, ``chart.npz`` and ``stage2.pt``. The neural ODE
    (:mod:`lagsplat.baselines.neural_ode`) is trained here on the same frozen chart with the Stage-2
    settings saved in ``stage2.pt`` (same windows, loss, budget and selection); both are scored by
    :func:`lagsplat.baselines.extrapolation.extrapolation_metrics` (settings: the ``extrapolation`` group).
    """
    import numpy as np
    import torch

    from lagsplat.baselines import ode_rollout, train_neural_ode
    from lagsplat.baselines.extrapolation import ExtrapolationConfig, extrapolation_metrics
    from lagsplat.dynamics.integrators import rollout
    from lagsplat.io.atomic import write_json
    from lagsplat.train.config import dataclass_from_mapping
    from lagsplat.train.stage2 import Stage2Config

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
        models[name] = extrapolation_metrics(chart, pred, xc.long_s, xc.sigma, ae, clip.images, xc.render_batch)
    models["neural_ode"].update(train_s=node_s, selected_train_nrmse=hist["selected_nrmse"])
    rec = {"system": str(cfg.system.name), "title": str(cfg.system.get("title", cfg.system.name)), "models": models,
           "names": {"lagsplat": "LaGSplat", "neural_ode": "latent neural ODE"}, "config": plain(cfg.get("extrapolation") or {})}  # fmt: skip
    write_json(a.extrapolation, rec)
    save_stage_config(cfg, "extrapolation")
    for name, m in models.items():
        print(f"{cfg.system.name} {name}: frequency error {100 * m['freq_error']:.1f} %, dissipation error {100 * m['dissipation_error']:.0f} %, "
              f"amplitude left after {m['long_s']:.0f} s {100 * m['amplitude_left']:.2f} %, PSNR {m['psnr_mean']:.2f} dB")  # fmt: skip


def stage_extrapolation_table(cfg: DictConfig) -> None:
    """``extrapolation.json`` of ``table.systems`` -> ``results/tables/extrapolation.tex``, ``.csv`` and ``.md`` (paper Table 3 layout)."""
    from lagsplat.artifacts import Artifacts, table_path
    from lagsplat.report.tables import extrapolation_table

    t = cfg.get("table", {})
    systems = list(t.get("systems", [cfg.system.name]))
    inputs = [Artifacts.for_run(cfg.results_dir, s).extrapolation for s in systems]
    extrapolation_table(inputs, table_path(cfg.results_dir, "extrapolation"))

"""The stage of the command line that compares the two decoder families at equal budget (paper App. B).

``python -m lagsplat deformation system=<name>`` reads the run's ``clip.npz``,
``stage1.pt`` and ``chart.npz``, trains (or reuses) the deformation-field
variant of Stage 1 on the same clip with the same settings and seed under
``variants/deformation/`` (:meth:`lagsplat.artifacts.Artifacts.decoder_variant`),
and writes ``results/tables/<deformation.table>.json``, ``.tex``, ``.csv`` and
``figures/deformation.png``; on a clip with a rigid-body truth (the synthetic
pendulums) it also pushes both decoders with the same forces
(:mod:`lagsplat.baselines.deformation_forces`), for which the deformation
variant gets its own chart and Stage 2.
"""

from __future__ import annotations

import time

from dataclasses import replace

from omegaconf import DictConfig, OmegaConf, open_dict

from lagsplat.artifacts import DEFORMATION_VARIANT
from lagsplat.cli_common import artifacts_of, plain, save_stage_config
from lagsplat.stages import stage_chart, stage_stage1, stage_stage2

__all__ = ["stage_deformation", "VARIANT"]

VARIANT = DEFORMATION_VARIANT
"""Folder of the deformation decoder's run under ``variants/`` (its Stage 1: ``artifacts.deformation_stage1``)."""


def _variant_cfg(cfg: DictConfig) -> DictConfig:
    """The run's configuration with the deformation decoder (every other setting, the seed included, the same)."""
    out = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    with open_dict(out):
        out.stage1.decoder = "deformation"
        out.variant = None
    return out


def stage_deformation(cfg: DictConfig) -> None:
    """Conditioned vs deformation-field decoder (paper App. B) -> ``results/tables/<deformation.table>.tex/.csv/.json``, ``figures/deformation.png``.

    Reads ``clip.npz``, ``stage1.pt`` and ``chart.npz`` of the run (and ``stage2.pt`` for the force
    comparison); trains the missing artifacts of ``variants/deformation/`` with the stage functions
    (Stage 1 always; chart and Stage 2 only for the forces). Both decoders are scored on the training
    frames (L1, 1 - SSIM), counted (parameters), and their velocity fields ``|J_i qdot|`` read at the
    training frame of largest ``|qdot|`` (roughness over ``deformation.k_neighbours`` neighbours;
    :mod:`lagsplat.baselines.deformation_compare`). Settings: the ``deformation`` group. Paths: the run's
    artifacts, ``artifacts.deformation_stage1`` (the variant's Stage 1) and ``table_json``, ``table_tex``,
    ``table_csv`` when given.
    """
    import numpy as np
    import torch

    from lagsplat.baselines.deformation_compare import DeformationCompareConfig, compare_decoder, fast_frame
    from lagsplat.io.atomic import write_json
    from lagsplat.motion import motion_masks
    from lagsplat.report.tables import deformation_table
    from lagsplat.train.config import dataclass_from_mapping
    from lagsplat.viz.deformation import deformation_figure, speed_render

    dc = dataclass_from_mapping(DeformationCompareConfig, plain(cfg.get("deformation") or {}), "deformation")
    if cfg.stage1.get("decoder", "conditioned") != "conditioned":
        raise ValueError(f"stage1.decoder={cfg.stage1.decoder}: the comparison starts from the run of the conditioned decoder")
    a = artifacts_of(cfg)
    a.require("clip", "stage1", "chart")
    av = replace(a.decoder_variant(VARIANT), stage1=a.deformation_stage1)
    vcfg = _variant_cfg(cfg)
    clip = a.load_clip()
    do_forces = dc.forces == "on" or (dc.forces == "auto" and "theta" in clip.meta)
    needed = [("stage1", stage_stage1)] + ([("chart", stage_chart), ("stage2", stage_stage2)] if do_forces else [])
    for name, fn in needed:
        if getattr(av, name).exists():
            print(f"[lagsplat] {cfg.system.name}: reusing {getattr(av, name)}", flush=True)
            continue
        if do_forces and name == "stage2":
            a.require("stage2")
        t0 = time.time()
        fn(vcfg, av)
        print(f"[lagsplat] {cfg.system.name}: deformation decoder {name} done in {time.time() - t0:.1f} s", flush=True)

    # the state: the training frame of largest |qdot| in the run's chart, read by each decoder through its own encoder
    chart = a.load_chart()
    frame, _ = fast_frame(np.asarray(chart.q), np.asarray(chart.t), clip.train_idx)
    try:  # the object and the background, from the clip alone (1 px margin)
        moving, static, _ = motion_masks(clip.images[clip.train_idx], 1.0)
    except ValueError:  # nothing moves: no split
        moving = static = None
    rows, fields, models = [], [], []
    for arts in (a, av):
        ae = arts.load_stage1()
        z = ae.encode_frames(clip.images[frame - 1 : frame + 2]).numpy().astype(float)  # raw latents of the frame and its neighbours
        t = np.asarray(clip.t, float)[frame - 1 : frame + 2]
        zdot = (z[2] - z[0]) / (t[2] - t[0])
        row, field = compare_decoder(ae, clip.images, clip.train_idx, z[1], zdot, dc, int(cfg.stage1.ssim_window), moving, static)
        row["zdot"] = zdot.tolist()
        rows.append(row)
        fields.append((field, z[1]))
        models.append((ae, arts))
        print(f"[lagsplat] {cfg.system.name} {row['decoder']}: L1 {row['l1']:.4f}, 1-SSIM {row['ssim_term']:.4f}, params {row['params_decoder']} "
              f"(+ encoder {row['params_total']}), {row['n_visible']} visible, median speed {row['speed_median_px_s']:.2f} px/s, "
              f"roughness {row['roughness_median_px_s']:.2f} px/s; on the object ({row['n_object']}): median speed "
              f"{row['speed_object_px_s']:.2f} px/s, roughness {row['roughness_object_px_s']:.2f} px/s; on the background "
              f"({row['n_static']}): median speed {row['speed_static_px_s']:.3f} px/s", flush=True)  # fmt: skip
    qdot = np.gradient(np.asarray(chart.q, float), np.asarray(chart.t, float), axis=0)[frame]
    rec = {"system": str(cfg.system.name), "title": str(cfg.system.get("title", cfg.system.name)),
           "state": {"frame": int(frame), "t_s": float(clip.t[frame]), "qdot_norm": float(np.linalg.norm(qdot))},
           "config": plain(cfg.get("deformation") or {}), "stage1": plain(cfg.stage1), "variant_dir": str(av.system_dir), "rows": rows}  # fmt: skip

    if do_forces:
        from lagsplat.baselines.deformation_forces import force_truth

        rec["forces"] = {}
        for ae, arts in models:
            model, _ = arts.load_stage2()
            try:
                res = force_truth(ae, arts.load_chart(), model.eval(), clip, float(cfg.forces.sigma), float(cfg.forces.min_transmittance))
            except ValueError as exc:  # e.g. no kappa reaches the calibration displacement: a result, recorded
                rec["forces"][ae.decoder.kind] = {"error": str(exc)}
                print(f"[lagsplat] {cfg.system.name} {ae.decoder.kind} forces: {exc}", flush=True)
                continue
            rec["forces"][ae.decoder.kind] = res
            for name, s in res["summary"].items():
                print(f"[lagsplat] {cfg.system.name} {ae.decoder.kind} forces, {name} read-out: {s['n_within']} of {s['n_scored']} within "
                      f"{res['tolerance']['deg']:g} deg and {res['tolerance']['pct']:g} %, max |dir| {s['max_abs_dir_err_deg']:.2f} deg, "
                      f"max |mag| {s['max_abs_mag_err_pct']:.1f} %, median |mag| {s['median_abs_mag_err_pct']:.1f} %", flush=True)  # fmt: skip

    out_json = a.table(cfg.results_dir, dc.table, ".json")
    write_json(out_json, rec)
    deformation_table(out_json, a.table(cfg.results_dir, dc.table), a.table(cfg.results_dir, dc.table, ".csv"))
    vmax = max(float(np.percentile(f["speed"][f["visible"]], 99)) if f["visible"].any() else 1.0 for f, _ in fields)
    names = {"conditioned": "conditioned (ours)", "deformation": "deformation field"}
    panels = []
    with torch.no_grad():
        for (ae, _), (f, z), row in zip(models, fields, rows):
            panels.append({"name": names[row["decoder"]], "image": f["image"].transpose(1, 2, 0).clip(0, 1),
                           "speed_image": speed_render(ae, z, f["speed"], vmax), "roughness": row["roughness_median_px_s"], "vmax": vmax})  # fmt: skip
    deformation_figure(panels, clip.images[frame], a.deformation_figure, title=f"{rec['title']}: |J_i qdot| at t = {rec['state']['t_s']:.2f} s")
    save_stage_config(cfg, "deformation")

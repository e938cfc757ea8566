"""Export one run's identified model into its ``export/`` folder (:func:`export_run`).

What is written (each file atomically):

* ``dynamics.py`` + ``weights.npz``: the right-hand side of paper Eq. 7 in NumPy (:mod:`lagsplat.export.dynamics_files`);
* ``M.pt``, ``V.pt``, ``C.pt`` (+ ``b.pt`` with inputs): TorchScript terms (:mod:`lagsplat.export.torchscript`);
* ``model.json``: parameters, chart, provenance, usage (:mod:`lagsplat.export.card`);
* ``trajectory.csv``, ``rollout.csv``: the encoded chart and a free rollout (:mod:`lagsplat.export.tables`);
* ``splat_q_<k>.ply``: the decoder at the chart's mean, min and max per coordinate (:mod:`lagsplat.export.splats`);
* ``backdrop.png``: a 2-D decoder's static layer, when it has one.

Supported: the models of the compiled rollout path (``mass`` scalar, constant or learned; convex or invex
potential; any number of inputs) with a conditioned 2-D or 3-D decoder. Anything else stops before a file
is written, with the reason (``mass="decoder"``, the deformation decoder).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch

from lagsplat.artifacts import Artifacts
from lagsplat.export.card import model_card
from lagsplat.export.dynamics_files import DYNAMICS_FILE, WEIGHTS_FILE, check_exportable, write_dynamics
from lagsplat.export.splats import splat_states, splats_at, write_splat_ply
from lagsplat.export.tables import free_rollout, rollout_columns, trajectory_columns, write_csv
from lagsplat.export.torchscript import TERMS, write_torchscript
from lagsplat.io.atomic import atomic_write, write_json

__all__ = ["FILES", "export_run"]

FILES = {
    DYNAMICS_FILE: "the identified dynamics, NumPy only: rhs(t, [q, qdot], u=None) for scipy's solve_ivp (paper Eq. 7)",
    WEIGHTS_FILE: "its float64 weights",
    TERMS["M"]: "TorchScript q [B,d] -> M(q) [B,d,d], inertia (float64)",
    TERMS["V"]: "TorchScript q [B,d] -> V(q) [B], potential energy (float64)",
    TERMS["C"]: "TorchScript q [B,d] -> C(q) [B,d,d], Rayleigh matrix, D = 1/2 qdot^T C qdot (float64)",
    TERMS["b"]: "TorchScript q [B,d] -> b(q) [B,n_u,d], input map, f = b(q)^T u (paper Eq. 6; with inputs only)",
    "model.json": "this description",
    "trajectory.csv": "t, q_i, qdot_i (central difference of the chart smoothed as Stage 2 reads it), u_j, split",
    "rollout.csv": "t, q_i, qdot_i: free rollout from the first training state (velocity Verlet at the frame interval)",
    "backdrop.png": "the 2-D decoder's static layer at the training resolution (not a Gaussian; with a static layer only)",
}
"""File name -> what it holds (``model.json``'s ``files``, the splat files added per run)."""


def _write_png(path: Path, rgb: np.ndarray) -> None:
    """``rgb [H,W,3]`` in [0, 1] as an 8-bit PNG, atomically."""
    import cv2

    ok, buf = cv2.imencode(".png", cv2.cvtColor(np.round(255 * np.clip(rgb, 0, 1)).astype(np.uint8), cv2.COLOR_RGB2BGR))
    if not ok:
        raise ValueError(f"{path}: could not encode the image as PNG")
    with atomic_write(path) as tmp:
        tmp.write_bytes(buf.tobytes())


def export_run(a: Artifacts, out_dir: str | Path | None = None, provenance: Mapping[str, Any] | None = None) -> dict[str, Path]:
    """Export the run ``a`` (its clip, Stage-1 model, chart, Stage-2 model and, if present, ``metrics.json``).

    Args:
        a: the run's artifact paths.
        out_dir: where to write (default ``a.export``, ``<model folder>/export/``).
        provenance: extra provenance for ``model.json`` (e.g. the configured source path).

    Returns:
        File name -> path of everything written.

    Raises:
        FileNotFoundError: naming the first missing input (``stage2.pt``, ``chart.npz``, ...) and its stage.
        ValueError: for a model or decoder the export does not support (module docstring); nothing is written then.
    """
    a.require("clip", "stage1", "chart", "stage2")
    out = Path(out_dir) if out_dir is not None else a.export
    model, ck = a.load_stage2()
    model.eval()
    check_exportable(model)
    ae, chart, clip = a.load_stage1(), a.load_chart(), a.load_clip()
    dec = ae.decoder
    if dec.kind not in ("conditioned", "conditioned3d"):
        raise ValueError(f"{a.stage1}: the {dec.kind!r} decoder has no conditioned Gaussians to export as .ply")
    if chart.d != model.d:
        raise ValueError(f"{a.chart}: chart of dimension {chart.d}, model {a.stage2} of dimension {model.d}")
    metrics = a.load_metrics()
    sigma = float((ck.get("config") or {}).get("sigma", 0.0))

    roll = rollout_columns(*free_rollout(model, chart, sigma))  # before any write: a chart it cannot start from stops here

    written = write_dynamics(model, out)
    idx = np.unique(np.linspace(0, len(chart.q) - 1, 8).round().astype(int))  # a few encoded frames to trace at
    written.update(write_torchscript(model, out, torch.as_tensor(chart.q[idx], dtype=torch.float64)))
    written["trajectory"] = write_csv(out / "trajectory.csv", trajectory_columns(chart, sigma))
    written["rollout"] = write_csv(out / "rollout.csv", roll)

    splats, files = [], {k: v for k, v in FILES.items() if (k != TERMS["b"] or model.n_u) and k != "backdrop.png"}
    for k, (label, q) in enumerate(splat_states(chart.q)):
        z = q @ chart.W_inv + chart.mean
        name = f"splat_q_{k}.ply"
        written[name] = write_splat_ply(out / name, splats_at(dec, z, ae.height, ae.width))
        splats.append({"file": name, "label": label, "q": q.tolist()})
        files[name] = f"the decoder's Gaussians at q = chart {label} (standard 3DGS .ply)"
    for stale in out.glob("splat_q_*.ply"):  # from an earlier export of another chart
        if stale.name not in written:
            stale.unlink()
    backdrop = dec.backdrop_image(ae.height, ae.width) if dec.n_space == 2 else None
    if backdrop is not None:
        with torch.no_grad():
            _write_png(out / "backdrop.png", backdrop.permute(1, 2, 0).double().numpy())
        written["backdrop"], files["backdrop.png"] = out / "backdrop.png", FILES["backdrop.png"]

    prov = {"run": str(a.model_dir), "stage2": str(a.stage2), "stage1": str(a.stage1), "chart": str(a.chart), "clip": str(a.clip),
            "metrics": str(a.metrics) if metrics is not None else None, **dict(provenance or {})}  # fmt: skip
    card = model_card(model, ck, chart, clip, dec, metrics, files, splats, prov)
    written["model"] = write_json(out / "model.json", card)
    return written

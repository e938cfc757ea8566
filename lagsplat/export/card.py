"""``model.json``: what the run knows about the identified model, its chart and where it came from.

:func:`model_card` gathers it from the loaded artifacts; nothing here trains or evaluates. The
frequencies and damping ratios are those ``metrics.json`` holds (the evaluate stage's), copied with their
definitions; the matrices at rest are read off the model (paper Eq. 7).
"""

from __future__ import annotations

import copy
import time
from typing import Any, Mapping

import numpy as np
import torch

from lagsplat.chart import Chart
from lagsplat.io.clip import Clip
from lagsplat.io.common import code_commit, jsonable
from lagsplat.models.lagrangian import Lagrangian

__all__ = ["FORMAT", "IDENTIFIED_METRICS", "HOW_TO_USE", "rest_matrices", "identified_metrics", "metric_intervals", "model_card"]

FORMAT = "lagsplat-export/1"
"""The export's format tag (``model.json``'s ``format``)."""

IDENTIFIED_METRICS = ("f_modes_hz", "zeta_modes", "f_sim_hz", "f_enc_hz", "f_enc_segment_hz", "f_truth_hz", "eps_freq", "eps_q", "eps_I_over_AE")
"""The ``metrics.json`` entries copied into ``model.json`` when present: the linearised model's natural
frequencies and damping ratios, the rollouts' and the video's frequencies, and the headline errors."""

HOW_TO_USE = (
    "dynamics.py (NumPy only; SciPy for solve_ivp) loads weights.npz from its own folder: "
    "from scipy.integrate import solve_ivp; import dynamics; "
    "sol = solve_ivp(dynamics.rhs, (0, T), np.r_[q0, qdot0], rtol=1e-9, atol=1e-11) integrates the identified "
    "Euler-Lagrange equation M(q) qddot = dT/dq - (d(M qdot)/dq) qdot - dV/dq - C(q) qdot + b(q)^T u; "
    "pass inputs with args=(u,) (a constant [n_u] or a function of t). dynamics.load() gives the model's terms "
    "(mass_matrix, potential, potential_grad, dissipation_matrix, input_map, energy) and rollout_verlet, the "
    "scheme rollout.csv was made with. In torch: torch.jit.load('M.pt') (V.pt, C.pt, b.pt), float64 q [B, d]. "
    "States are in the whitened chart: q = (z - chart.mean) @ chart.W, z the encoder's latent. "
    "splat_q_<k>.ply are the decoder's Gaussians at the states listed under 'splats' (standard 3DGS layout; "
    "a 2-D decoder's image plane is seen as the camera saw it from z < 0 looking along +z, y down). "
    "trajectory.csv and rollout.csv: header row, comma-separated, t in seconds."
)


def rest_matrices(model: Lagrangian) -> dict[str, list]:
    """``M``, ``C`` and the stiffness ``K = d^2V/dq^2`` at the rest state ``q*`` (``[d,d]`` lists, float64 copy)."""
    m = copy.deepcopy(model).double().eval()
    q = m.q_rest.detach().clone()
    with torch.no_grad():
        M, C = m.mass_matrix(q[None])[0], m.dissipation_matrix(q[None])[0]
    K = torch.autograd.functional.jacobian(lambda x: m.potential_grad(x[None], create_graph=True)[0], q)
    return {"M": M.tolist(), "C": C.tolist(), "K": K.detach().tolist()}


def identified_metrics(metrics: Mapping[str, Any] | None) -> dict[str, Any]:
    """The :data:`IDENTIFIED_METRICS` entries of a ``metrics.json`` document (``{value, units, definition}`` each)."""
    block = (metrics or {}).get("metrics") or {}
    out = {}
    for name in IDENTIFIED_METRICS:
        e = block.get(name)
        if isinstance(e, Mapping) and "value" in e:
            out[name] = {k: e[k] for k in ("value", "units", "definition", "horizon") if k in e}
    return out


def metric_intervals(metrics: Mapping[str, Any] | None) -> dict[str, Any]:
    """Every entry of ``metrics.json``'s metrics whose name mentions an interval (e.g. ``free_intervals``), as stored."""
    block = (metrics or {}).get("metrics") or {}
    return {k: v for k, v in block.items() if "interval" in k.lower()}


def model_card(
    model: Lagrangian, checkpoint: Mapping[str, Any], chart: Chart, clip: Clip, decoder: Any, metrics: Mapping[str, Any] | None,
    files: Mapping[str, str], splats: list[dict], provenance: Mapping[str, Any],
) -> dict[str, Any]:  # fmt: skip
    """The ``model.json`` document.

    Args:
        model, checkpoint: the Stage-2 Lagrangian and its ``stage2.pt`` dictionary (settings, history).
        chart, clip: the run's chart and clip (whitening, timing, provenance).
        decoder: the Stage-1 decoder (its kind, size and background).
        metrics: ``metrics.json``, or ``None`` when the model was not evaluated.
        files: file name -> what it holds; splats: ``[{"file", "label", "q"}]``.
        provenance: the run's paths and source (merged with the clip's record and the code's commit).

    Returns:
        A JSON-serialisable dict: ``format``, ``d``, ``units``, ``dt_s``, ``fps``, ``model`` (inertia form,
        scales, rest state, ``M``/``C``/``K`` at rest, Stage-2 settings), ``identified`` (metrics.json),
        ``intervals``, ``chart`` (whitening ``W``/``mean``, ``G_bar``, range), ``decoder``, ``splats``,
        ``files``, ``provenance`` and ``how_to_use``.
    """
    dt = float(np.median(np.diff(chart.t)))
    meta = clip.meta or {}
    hist = checkpoint.get("history") or {}
    pot = model.potential_hat
    backdrop = getattr(decoder, "backdrop_raw", None) is not None
    card = {
        "format": FORMAT,
        "system": meta.get("system"),
        "d": int(model.d),
        "n_u": int(model.n_u),
        "u_names": list(clip.u_names),
        "units": {
            "t": "s", "q": "whitened chart units, q = (z - chart.mean) @ chart.W (z: the encoder's latent)",
            "qdot": "chart units per s",
            "energy": "M, C, V and b share one scale that video cannot fix (the energy gauge, paper §3.4); their ratios are identified",
            "u": "as measured (the clip's actuation channels)",
            "splat_xyz": "pixels of the training resolution, image on z = 0 (2-D decoder); world units (3-D decoder)",
        },  # fmt: skip
        "dt_s": dt,
        "fps": 1.0 / dt,
        "n_frames": int(len(chart.t)),
        "model": {
            "inertia": model.mass_kind, "potential": model.potential_kind, "c0": float(model.c0),
            "exp_s_M": float(torch.exp(model.s_M.detach().double())), "exp_s_V": float(torch.exp(model.s_V.detach().double())),
            "eps_V": float(pot.eps), "q_rest": model.q_rest.detach().double().tolist(), "at_rest": rest_matrices(model),
            "stage2": checkpoint.get("config"), "selected_epoch": hist.get("selected_epoch"), "f_train_hz": hist.get("f_train_hz"),
        },  # fmt: skip
        "identified": identified_metrics(metrics),
        "intervals": metric_intervals(metrics),
        "chart": {
            "W": chart.W.tolist(), "mean": chart.mean.tolist(), "W_inv": chart.W_inv.tolist(), "G_bar": chart.G_bar.tolist(),
            "height": int(chart.height), "width": int(chart.width), "q_min": chart.q.min(0).tolist(),
            "q_mean": chart.q.mean(0).tolist(), "q_max": chart.q.max(0).tolist(),
        },  # fmt: skip
        "decoder": {"kind": decoder.kind, "n_gaussians": int(decoder.K), "background": decoder.background.tolist(), "backdrop": backdrop},
        "splats": splats,
        "files": dict(files),
        "provenance": {
            **dict(provenance),
            "source": meta.get("source"), "frames": meta.get("frames"), "crop": meta.get("crop"), "resize": meta.get("resize"),
            "original_size": meta.get("original_size"), "timing_fps": (meta.get("timing") or {}).get("fps"),
            "code": code_commit(), "exported": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "evaluated": metrics is not None,
        },  # fmt: skip
        "how_to_use": HOW_TO_USE,
    }
    return jsonable(card)  # NumPy values as JSON ones, non-finite numbers as null

"""Extrapolation figure in the layout of the paper's Fig. 5 (protocol of §4.3).

One chart, the frozen LaGSplat encoder's, along the most visible direction of ``G_bar``: the encoded
real video over the filmed window (shaded; the training part darker), then each model's free
extrapolation from the first held-out frame for ``figure_s`` seconds, and, on a second axis sharing
the vertical scale, its last natural period before ``long_s`` (1000 s in the paper). A dissipative
model is flat there; an unconstrained predictor may still be orbiting.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lagsplat.io.atomic import atomic_write  # noqa: E402

__all__ = ["extrapolation_figure"]

_STYLE = {"lagsplat": ("tab:blue", "-"), "neural_ode": ("tab:orange", "--"), "gp2d": ("tab:green", "-."), "gaussian_prediction": ("tab:red", ":")}


def extrapolation_figure(record: str | Path | dict, out_png: str | Path) -> Path:
    """Draw the figure of an ``extrapolation.json`` record (module docstring) into ``out_png`` (written atomically).

    Args:
        record: the record, or the path of ``extrapolation.json`` (:func:`lagsplat.stages_baselines.stage_extrapolation`).
        out_png: where the PNG goes.

    Returns:
        ``out_png`` as a ``Path``.

    Raises:
        ValueError: if the record has no ``real`` trace or no model with a ``trace`` (written by an older version:
            run the extrapolation stage again).
    """
    rec = json.loads(Path(record).read_text()) if not isinstance(record, dict) else record
    real = rec.get("real")
    models = {k: m for k, m in rec.get("models", {}).items() if m.get("trace")}
    if real is None or not models:
        raise ValueError(f"{record if not isinstance(record, dict) else 'record'}: no traces to draw (run the extrapolation stage again)")
    t0 = float(real["t_held_out"])
    fig, (ax, ax_far) = plt.subplots(1, 2, figsize=(10, 3.4), sharey=True, gridspec_kw={"width_ratios": [3.2, 1], "wspace": 0.05})
    ax.axvspan(0.0, t0, color="0.85", lw=0, label="filmed, training")
    ax.axvspan(t0, float(real["t_end"]), color="0.93", lw=0, label="filmed, held out")
    ax.plot(real["t"], real["p"], color="k", lw=1.0, label="real video (encoded)")
    far_lo, far_hi = np.inf, -np.inf
    for key, m in models.items():
        tr, name = m["trace"], rec.get("names", {}).get(key, key)
        color, ls = _STYLE.get(key, (None, "-"))
        dt = float(tr["dt"])
        if tr.get("near") is not None:
            near = np.asarray(tr["near"], float)
            ax.plot(t0 + dt * np.arange(len(near)), near, color=color, ls=ls, lw=1.2, label=name)
        if tr.get("far") is not None:
            far = np.asarray(tr["far"], float)
            t_far = t0 + float(tr["long_s"]) - dt * np.arange(len(far))[::-1]
            ax_far.plot(t_far, far, color=color, ls=ls, lw=1.2)
            far_lo, far_hi = min(far_lo, t_far[0]), max(far_hi, t_far[-1])
    lo, hi = float(np.min(real["p"])), float(np.max(real["p"]))
    ax.set_ylim(lo - 0.75 * (hi - lo), hi + 0.75 * (hi - lo))  # room for 2.5x the filmed amplitude; a runaway model leaves the frame
    ax.set_xlim(0.0, max(t0 + max(float(m["trace"]["dt"]) * len(m["trace"]["near"] or []) for m in models.values()), float(real["t_end"])))
    ax.set_xlabel("time from the filmed window's start (s)")
    ax.set_ylabel("q along the top direction of G_bar")
    ax.set_title(f"{rec.get('title', rec.get('system', ''))}: free extrapolation from the first held-out frame", fontsize=10)
    ax.legend(fontsize=7, loc="upper right", ncol=2, framealpha=0.9)
    if np.isfinite(far_lo):
        ax_far.set_xlim(far_lo, far_hi)
        ax_far.set_xlabel("time (s), last period")
        ax_far.set_title(f"after {max(float(m['trace']['long_s']) for m in models.values()):g} s", fontsize=10)
    for side, a in (("right", ax), ("left", ax_far)):
        a.spines[side].set_visible(False)
    ax_far.tick_params(left=False)
    out = Path(out_png)
    with atomic_write(out) as tmp:
        fig.savefig(tmp, format="png", dpi=130, bbox_inches="tight")
    plt.close(fig)
    return out

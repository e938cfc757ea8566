"""The held-out gap figure: the encoded held-out video against one free rollout of each model (before / after the refit, control).

:func:`lagsplat.diagnose.report.diagnose_artifacts` writes it as the diagnosis
figure ``DIAGNOSIS_FIGURES["gap"]`` of :mod:`lagsplat.artifacts`; the rollouts
start past the smoothing's edge, as the gap metrics of
:func:`lagsplat.diagnose.gap.held_out_gap` do.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lagsplat import metrics, timeseries
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.io.atomic import atomic_write
from lagsplat.io.clip import HELD_OUT

__all__ = ["plot_gap"]


@torch.no_grad()
def plot_gap(chart: Any, runs: Mapping[str, tuple[Any, Any]], path: str | Path, title: str = "", sigma: float = 1.0) -> Path | None:
    """Figure: the longest held-out segment, encoded, with one free rollout per model (started past the smoothing edge, like the metrics).

    Args:
        chart: the chart (encoded trajectory).
        runs: ``{label: (model, chart_the_model_reads)}``.
        path: PNG written atomically.
        title: figure title.
        sigma: smoothing of the encoded trajectory, frames.

    Returns:
        ``path``, or ``None`` when the chart has no held-out segment of 4 frames.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    held = [s for s in chart.segments(HELD_OUT) if len(s) >= 4]
    if not held:
        return None
    ho = max(held, key=len)
    dt = float(np.median(np.diff(chart.t)))
    top = metrics.top_direction(chart.G_bar)
    q_s = timeseries.gaussian_smooth(chart.q[ho], sigma)
    fig, ax = plt.subplots(1, 1, figsize=(10, 3.6))
    ax.plot(chart.t[ho], q_s @ top, color="k", lw=1.6, label="encoded (held out)")
    a = metrics.rollout_start(sigma, len(ho), 3)  # past the smoothing's edge, as the metrics start
    for i, (label, (model, ch)) in enumerate(runs.items()):
        q0, v0 = initial_state(q_s, np.array([a]), dt)
        u = ch.u[ho[a:]]
        sim, _ = rollout(model, q0, v0, dt, len(ho) - a, u=actuation_schedule(u[None] if u.shape[1] else None, dt))
        ax.plot(chart.t[ho[a:]], sim[0].double().numpy() @ top, lw=1.1, color=f"C{i}", label=label, alpha=0.9)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("q on top G_bar direction")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title((title + ": " if title else "") + f"held-out gap, one free rollout from held-out frame {a}", fontsize=9)
    path = Path(path)
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path

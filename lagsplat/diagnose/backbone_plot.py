"""The backbone figure: frequency and damping ratio against amplitude, the video's swings as markers, each model's
free releases as lines (:mod:`lagsplat.diagnose.backbone` computes the record).

:func:`lagsplat.diagnose.report.diagnose_artifacts` writes it as the diagnosis figure
``DIAGNOSIS_FIGURES["backbone"]`` of :mod:`lagsplat.artifacts`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from lagsplat.io.atomic import atomic_write

__all__ = ["plot_backbone"]


def plot_backbone(rec: Mapping[str, Any], path: str | Path, title: str = "") -> Path | None:
    """Figure: two panels sharing the amplitude axis (chart units), frequency (Hz) above, damping ratio below.

    Video readings are black markers (filled: training frames, open: held-out frames); each model's readings are
    one line per release, in its own colour; the recorded amplitude range is shaded.

    Args:
        rec: the record of :func:`~lagsplat.diagnose.backbone.backbone`.
        path: PNG written atomically.
        title: figure title.

    Returns:
        ``path``, or ``None`` when the record was not read (``rec["done"]`` false).
    """
    if not rec.get("done"):
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(7.5, 6.5), sharex=True)
    v = rec["video"]
    a_lo, a_hi = rec["amplitude_range"]
    for k, (a_key, y_key, h_key) in enumerate((("amplitude", "frequency_hz", "held_out"), ("zeta_amplitude", "zeta", "zeta_held_out"))):
        a, y, h = np.asarray(v[a_key]), np.asarray(v[y_key]), np.asarray(v[h_key], bool)
        ax[k].axvspan(a_lo, a_hi, color="0.92", lw=0, zorder=0)
        ax[k].plot(a[~h], y[~h], "o", ms=4.5, color="k", label="video (training frames)")
        if h.any():
            ax[k].plot(a[h], y[h], "o", ms=4.5, mfc="none", color="k", label="video (held-out frames)")
        for i, (label, m) in enumerate(rec["models"].items()):
            if "error" in m:
                continue
            rel = np.asarray(m["release" if k == 0 else "zeta_release"], int)
            am, ym = np.asarray(m[a_key]), np.asarray(m[y_key])
            for j in np.unique(rel):
                s = rel == j
                order = np.argsort(am[s])
                ax[k].plot(am[s][order], ym[s][order], "-", lw=1.4, color=f"C{i}", alpha=0.85, label=label if j == rel.min() else None)
    ax[0].set_ylabel("frequency (Hz)")
    ax[1].set_ylabel("damping ratio zeta")
    ax[1].set_xlabel("amplitude (chart units, top G_bar direction; half the peak-to-peak swing)")
    ax[0].legend(fontsize=8, loc="best")
    ax[0].set_title((title + ": " if title else "") + "backbone (shaded: the recorded amplitudes)", fontsize=9)
    for a in ax:
        a.grid(alpha=0.3)
    path = Path(path)
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path

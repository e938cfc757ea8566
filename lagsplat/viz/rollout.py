"""Rollout figure in the spirit of the paper's Fig. 3 (protocol of §4.1, "Reading the rollout figures")."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from lagsplat import timeseries  # noqa: E402
from lagsplat.artifacts import Artifacts  # noqa: E402
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout  # noqa: E402
from lagsplat.io.atomic import atomic_write  # noqa: E402
from lagsplat.io.clip import HELD_OUT, TRAIN  # noqa: E402

__all__ = ["rollout_figure", "held_out_frequency", "metrics_line", "visibility_basis"]


def metrics_line(metrics: dict, no_held_out: str | None = None) -> str:
    """The key metrics of a ``metrics.json`` block in one line, those present and finite (paper §4.1):
    ``eps_freq`` (%), ``eps_q``, ``eps_I / eps_AE``, and the soft-robot protocol's ``mse_0p5s``; for a clip
    without held-out frames (``no_held_out``, ``metrics.json``'s ``held_out`` note) the in-sample
    ``eps_freq_in_sample`` and the damping ratios ``zeta_sim`` / ``zeta_enc``, followed by the note. Where
    ``metrics.json`` has them, the frequency and damping ratio with their 90 % intervals
    (:mod:`lagsplat.evaluate.intervals`) come after."""
    parts = []
    keys = (("eps_freq", "eps_freq {:.2%}"), ("eps_q", "eps_q {:.3f}"), ("eps_I_over_AE", "eps_I / eps_AE {:.2f}"), ("mse_0p5s", "MSE(0.5 s) {:.2e}"))
    if no_held_out:
        keys = (("eps_freq_in_sample", "eps_freq in-sample {:.2%}"), ("zeta_sim", "zeta model {:.3f}"), ("zeta_enc", "video {:.3f}"))
    for key, fmt in keys:
        v = (metrics.get(key) or {}).get("value")
        if isinstance(v, (int, float)) and np.isfinite(v):
            parts.append(fmt.format(v))
    for key, fmt in (("f_sim_hz", "f {:.3f} Hz [{:.3f}, {:.3f}]"), ("zeta_sim", "zeta {:.3f} [{:.3f}, {:.3f}]")):
        v, iv = (metrics.get(key) or {}).get("value"), (metrics.get(f"{key}_interval") or {}).get("value")
        if isinstance(v, (int, float)) and iv is not None:  # the calibrated 90 % interval (lagsplat.evaluate.intervals)
            parts.append(fmt.format(v, *iv))
    if no_held_out:
        return ", ".join(parts) + f"  (in-sample: {no_held_out})"
    return ", ".join(parts) + ("  (held-out frames)" if parts else "")


def visibility_basis(G_bar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenbasis of the visibility metric, most visible first: ``(share [d], V [d,d])``, ``share`` each
    direction's part of ``trace G_bar`` and ``V[:, k]`` its unit direction (plot ``q @ V``)."""
    lam, V = np.linalg.eigh(0.5 * (G_bar + G_bar.T))
    order = np.argsort(lam)[::-1]
    return lam[order] / lam.sum(), V[:, order]


def held_out_frequency(metrics: dict) -> float:
    """The encoded held-out frequency (Hz) a ``metrics.json`` block gives: the paper protocol's
    ``f_enc_segment_hz`` (whole held-out segment), else the mean over windows ``f_enc_hz`` (both protocols),
    else (held-out frames at rest, :mod:`lagsplat.evaluate.rest`) the model's slowest mode ``f_modes_hz``.

    Raises:
        ValueError: if none is present and finite.
    """
    for key in ("f_enc_segment_hz", "f_enc_hz"):
        v = (metrics.get(key) or {}).get("value")
        if v is not None and np.isfinite(v) and v > 0:
            return float(v)
    modes = [f for f in (metrics.get("f_modes_hz") or {}).get("value") or [] if f is not None and np.isfinite(f) and f > 0]
    if modes:
        return float(min(modes))
    raise ValueError("metrics.json has no finite f_enc_segment_hz, f_enc_hz or f_modes_hz: evaluate the run first")


def rollout_figure(artifacts: Artifacts | str | Path, title: str = "", provenance: str = "", sigma: float = 1.0) -> Path:
    """One free rollout across the train / held-out boundary, latent and images.

    The model starts from the encoded state (position and velocity) one
    natural period before the first held-out frame (past the smoothing's edge
    when that is a recording's first frame) and is never re-anchored.
    Top: each latent coordinate, ordered by decreasing visibility (share of
    ``trace G_bar`` in the label), encoded vs predicted, held-out shaded.
    Bottom: at three held-out times, the real frame, the render at the encoded
    ``q`` (the autoencoder's own floor) and the render at the predicted ``q``.
    A clip identified on all its frames (``metrics.json``'s ``held_out`` note,
    :mod:`lagsplat.evaluate.in_sample`) has no held-out part: the rollout starts
    past the smoothing's edge of its longest training segment and runs through it,
    in-sample, the note in the title.

    Args:
        artifacts: the run's :class:`~lagsplat.artifacts.Artifacts` (clip, stage1, chart,
            stage2, metrics; the figure goes to ``artifacts.rollout_figure``), or a
            ``results/<system>`` folder in the standard layout.
        title: figure title.
        provenance: data source line printed under the figure.
        sigma: latent smoothing (frames) used for the initial state.

    Returns:
        Path of the figure (``figures/rollout.png``).

    Raises:
        FileNotFoundError: naming a missing artifact (``metrics.json`` included: the figure prints its metrics).
    """
    a = artifacts if isinstance(artifacts, Artifacts) else Artifacts.at(artifacts)
    a.require("clip", "stage1", "chart", "stage2", "metrics")
    clip, chart, ae = a.load_clip(), a.load_chart(), a.load_stage1()
    model, _ = a.load_stage2()
    doc = a.load_metrics()
    metrics, note = doc["metrics"], doc.get("held_out")
    f_enc = held_out_frequency(metrics)
    dt = float(np.median(np.diff(chart.t)))
    held = chart.segments(HELD_OUT)
    if held:
        ho = max(held, key=len)
        period = int(round(1.0 / (f_enc * dt)))
        s0 = max(int(ho[0]) - period, 0)
        if chart.episode[s0] != chart.episode[ho[0]]:  # a held-out recording: start at its first frame
            s0 = int(ho[0])
    else:  # a clip identified on all its frames: the rollout runs through the longest training segment, in-sample
        ho = max(chart.segments(TRAIN), key=len)
        s0 = int(ho[0])
    # smooth from `edge` frames earlier where the recording has them, else start `edge` frames in:
    # the smoothing's replicated edge would bias the initial velocity (lagsplat.timeseries.smoothing_edge)
    edge = timeseries.smoothing_edge(sigma)
    first = int(np.flatnonzero(chart.episode == chart.episode[s0])[0])
    lead = max(s0 - edge, first)
    s0 = min(max(s0, lead + edge), int(ho[-1]) - 2)
    idx = np.arange(s0, int(ho[-1]) + 1)
    q_s = timeseries.gaussian_smooth(chart.q[lead : int(ho[-1]) + 1], sigma)[s0 - lead :]
    q0, v0 = initial_state(q_s, np.array([0]), dt)
    pred, _ = rollout(model, q0, v0, dt, len(idx), u=actuation_schedule(chart.u[idx][None], dt))
    pred = pred[0].numpy()

    share, V = visibility_basis(chart.G_bar)
    enc_c, pred_c = q_s @ V, pred @ V
    t = chart.t[idx]

    picks = [int(ho[len(ho) // 3]), int(ho[2 * len(ho) // 3]), int(ho[-1])]
    with torch.no_grad():
        z_enc = chart.to_raw(torch.as_tensor(chart.q[picks], dtype=torch.float32))
        z_pred = chart.to_raw(torch.as_tensor(pred[[p - s0 for p in picks]], dtype=torch.float32))
        r_enc = ae.decode(z_enc).permute(0, 2, 3, 1).numpy()
        r_pred = ae.decode(z_pred).permute(0, 2, 3, 1).numpy()
    real = clip.images[picks] / 255.0

    dd = chart.d
    img_h = max(0.45, 2.8 * chart.height / chart.width)  # inches per image row (panels ~2.8 in wide)
    fig = plt.figure(figsize=(9, 2.0 * dd + 3 * (img_h + 0.3) + 0.6))
    gs = fig.add_gridspec(dd + 3, 3, height_ratios=[2.0] * dd + [img_h + 0.3] * 3)
    for k in range(dd):
        ax = fig.add_subplot(gs[k, :])
        if held:
            ax.axvspan(chart.t[ho[0]], chart.t[ho[-1]], color="0.9", label="held out")
        ax.plot(t, enc_c[:, k], ".", ms=2.5, color="k", label="encoded")
        ax.plot(t, pred_c[:, k], "-", lw=1.2, color="tab:red", label="predicted (free rollout)")
        ax.set_ylabel(f"q{k + 1}: mode {k + 1} of G_bar\n({100 * share[k]:.0f} % of the visibility)", fontsize=8)
        ax.axvline(t[0], color="tab:red", lw=1.0, ls="--", label=f"rollout starts, t = {t[0]:.2f} s")
        for p in picks:
            ax.axvline(chart.t[p], color="tab:blue", lw=0.6, ls=":")
        if k == 0:
            ax.legend(loc="upper right", fontsize=7, ncol=4)
            ax.set_title(title + ("\n" if title else "") + metrics_line(metrics, None if held else (note or "no held-out frames")), fontsize=9)
    ax.set_xlabel("time (s)")
    labels = ["real", "at encoded q", "at predicted q"]
    for r, imgs in enumerate([real, r_enc, r_pred]):
        for c in range(3):
            ax = fig.add_subplot(gs[dd + r, c])
            ax.imshow(np.clip(imgs[c], 0, 1), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if c == 0:
                ax.set_ylabel(labels[r], fontsize=8)
            if r == 0:
                ax.set_title(f"t = {chart.t[picks[c]]:.2f} s", fontsize=8)
    if provenance:
        fig.text(0.01, 0.005, f"data: {provenance}", fontsize=6, color="0.4")
    fig.tight_layout(rect=(0, 0.015, 1, 1))
    out = a.rollout_figure
    with atomic_write(out) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return out

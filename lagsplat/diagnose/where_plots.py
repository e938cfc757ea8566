"""Figures of where the identified model departs from the video: time, state, latent directions, image (paper §3.3 diagnosis; :mod:`lagsplat.diagnose.where` computes them)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from lagsplat.artifacts import DIAGNOSIS_FIGURES
from lagsplat.diagnose.localise import ImageLocalisation, Where
from lagsplat.diagnose.where import (
    REGIONS,
    LatentLocalisation,
    StateLocalisation,
)
from lagsplat.diagnose.where_time import TimeLocalisation
from lagsplat.io.atomic import atomic_write


def _save(fig: Any, path: Path) -> Path:
    import matplotlib.pyplot as plt

    path = Path(path)
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_time(tl: TimeLocalisation, path: Path, title: str = "") -> Path:
    """Figure: encoded coordinate with rollouts, rollout error over its floor, residual over noise, flagged windows shaded."""
    plt = _plt()
    fig, ax = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for k in np.unique(tl.segment):
        m = tl.segment == k
        ax[0].plot(tl.t[m], tl.p_enc[m], color="k", lw=1.2, label="encoded" if k == 0 else None)
        ax[1].semilogy(tl.t[m], np.maximum(tl.ratio_roll[m], 1e-3), color="C0", lw=1)
        ax[2].semilogy(tl.t[m], np.maximum(tl.z2[m], 1e-3), color="C3", lw=1)
    for i, (t, p) in enumerate(tl.p_sim[:: max(1, len(tl.p_sim) // 40)]):
        ax[0].plot(t, p, color="C1", lw=0.7, alpha=0.6, label="free rollouts" if i == 0 else None)
    for a, lab in ((ax[1], "rollout error / AE floor"), (ax[2], "residual / chart noise (z^2)")):
        a.axhline(1.0, color="0.5", lw=0.8, ls=":")
        a.set_ylabel(lab, fontsize=8)
    for w in tl.windows:
        for a in ax:
            a.axvspan(w["t_start_s"], w["t_end_s"], color="C3", alpha=0.15, lw=0)
    ax[0].set_ylabel("q on top G_bar direction", fontsize=8)
    ax[0].legend(fontsize=7, loc="upper right")
    ax[2].set_xlabel("time (s)")
    fig.suptitle(
        (title + ": " if title else "") + f"where in time: {tl.horizon}-frame free rollouts; shaded: rollout error and residual "
        f"both above the floor factor ({len(tl.windows)} window(s))", fontsize=9,
    )  # fmt: skip
    return _save(fig, path)


def plot_state(st: StateLocalisation, path: Path, title: str = "") -> Path:
    """Figure: phase portrait coloured by the residual, region boundaries, and the residual share per region."""
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.5), gridspec_kw={"width_ratios": [1.3, 1]})
    sc = ax[0].scatter(st.x, st.y, c=np.log10(np.maximum(st.z2, 1e-3)), s=4, cmap="viridis")
    fig.colorbar(sc, ax=ax[0], label="log10 residual z^2")
    th = np.linspace(0, 2 * np.pi, 200)
    rr = st.bounds["rest_radius"]
    ax[0].plot(rr * np.cos(th), rr * np.sin(th), color="0.3", ls="--", lw=1)
    tr = st.bounds["turning_ratio"]
    lim = 1.3 * max(1.0, float(np.max(np.abs(st.x))), float(np.max(np.abs(st.y))))
    rmax = np.linspace(rr, lim * 1.5, 2)
    for sx in (-1, 1):
        for sy in (-1, 1):
            ax[0].plot(sx * rmax * math.sqrt(1 - tr**2), sy * rmax * tr, color="0.4", lw=0.8, ls="--")
    vq = st.bounds["high_speed_y"]
    for sy in (-1, 1):
        ax[0].axhline(sy * vq, color="C3", lw=0.8, ls=":")
    ax[0].set_xlim(-lim, lim)
    ax[0].set_ylim(-lim, lim)
    ax[0].set_xlabel("position (units of the oscillation)")
    ax[0].set_ylabel("velocity / omega")
    names = list(REGIONS)
    xs = np.arange(len(names))
    ax[1].bar(xs - 0.2, [st.regions[k]["sample_share"] for k in names], 0.4, label="share of samples", color="0.7")
    ax[1].bar(xs + 0.2, [st.regions[k]["residual_share"] for k in names], 0.4, label="share of residual", color="C3")
    ax[1].set_xticks(xs, [n.replace("_", " ") for n in names], fontsize=8)
    ax[1].legend(fontsize=8)
    fig.suptitle((title + ": " if title else "") + "where in state (phase portrait of the most visible coordinate)", fontsize=9)
    return _save(fig, path)


def plot_latent(lt: LatentLocalisation, path: Path, title: str = "") -> Path:
    """Figure: per eigen-direction of G_bar, visibility, residual and rollout shares (G_bar-weighted)."""
    plt = _plt()
    d = len(lt.eigenvalues)
    fig, ax = plt.subplots(1, 1, figsize=(max(5, 1.5 * d + 3), 3.8))
    xs = np.arange(d)
    vis = lt.eigenvalues / max(float(lt.eigenvalues.sum()), 1e-300)
    ax.bar(xs - 0.27, vis, 0.27, label="visibility (lambda share)", color="0.7")
    ax.bar(xs, lt.residual_share_G, 0.27, label="residual share (G_bar-weighted)", color="C3")
    if lt.rollout_share_G is not None:
        ax.bar(xs + 0.27, lt.rollout_share_G, 0.27, label="rollout-gap share (G_bar-weighted)", color="C0")
    ax.set_xticks(xs, [f"e{k + 1}\nlambda={lt.eigenvalues[k]:.2g}" for k in range(d)], fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.legend(fontsize=7)
    fig.suptitle((title + ": " if title else "") + "where along latent directions (eigenvectors of G_bar)", fontsize=9)
    return _save(fig, path)


def plot_image(im: ImageLocalisation, path: Path, title: str = "") -> Path:
    """Figure: mean frame, AE error, rollout error, excess map, and the Gaussians the excess is attributed to."""
    plt = _plt()
    H, W = im.err_ae.shape
    if W > 2 * H:  # wide strips: three rows of two
        fig, axs = plt.subplots(3, 2, figsize=(13, 3 * (6 * H / W + 0.9) + 0.6), layout="constrained")
    else:
        fig, axs = plt.subplots(2, 3, figsize=(12, max(4.5, 8 * H / W + 1.5)), layout="constrained")
    ax = list(axs.ravel())
    ax[0].imshow(np.clip(im.mean_frame, 0, 1))
    ax[0].set_title("mean frame", fontsize=8)
    vmax = float(max(im.err_ae.max(), im.err_roll.max(), 1e-12))
    for a, m, lab in ((ax[1], im.err_ae, "AE reconstruction error"), (ax[2], im.err_roll, "rollout render error")):
        h = a.imshow(m, cmap="magma", vmin=0, vmax=vmax)
        a.set_title(lab, fontsize=8)
        fig.colorbar(h, ax=a, fraction=0.046)
    lim = float(np.max(np.abs(im.excess))) or 1e-12
    h = ax[3].imshow(im.excess, cmap="RdBu_r", vmin=-lim, vmax=lim)
    ax[3].set_title("excess over the AE floor", fontsize=8)
    fig.colorbar(h, ax=ax[3], fraction=0.046)
    ax[4].imshow(np.clip(im.mean_frame, 0, 1), alpha=0.6)
    top = np.argsort(im.share)[::-1][: max(50, im.top_n)]
    s = im.share[top]
    ok = s > 0
    ax[4].scatter(im.positions[top][ok, 0] - 0.5, im.positions[top][ok, 1] - 0.5, s=400 * s[ok] / max(float(s.max()), 1e-12),
                  facecolors="none", edgecolors=np.where(im.moving[top][ok], "C3", "C0"), lw=1.2)  # fmt: skip
    ax[4].set_xlim(-0.5, W - 0.5)
    ax[4].set_ylim(H - 0.5, -0.5)
    ax[4].set_title("Gaussians carrying the excess (red: moving, blue: static)", fontsize=8)
    k = min(im.top_n, len(im.share))
    order = np.argsort(im.share)[::-1][:k]
    ax[5].barh(np.arange(k)[::-1], im.share[order], color=np.where(im.moving[order], "C3", "C0"))
    ax[5].set_yticks(np.arange(k)[::-1], [f"#{i}" for i in order], fontsize=7)
    ax[5].set_xlabel("share of the excess", fontsize=8)
    ax[5].set_title(f"moving {im.share[im.moving].sum():.0%}, static {im.share[~im.moving].sum():.0%}, background {im.background_share:.0%}", fontsize=8)
    for a in ax[:5]:
        a.set_xticks([])
        a.set_yticks([])
    fig.suptitle((title + ": " if title else "") + f"where in the image ({len(im.frames)} rollout frames)", fontsize=9)
    return _save(fig, path)


def plot_where(where: Where, fig_dir: str | Path, title: str = "") -> dict[str, str]:
    """Write one figure per aspect under ``fig_dir`` (``where_time.png``, ``where_state.png``,
    ``where_latent.png``, ``where_image.png``), atomically.

    Returns:
        ``{aspect: path}`` of the figures written (aspects that are ``None`` are skipped).
    """
    fig_dir = Path(fig_dir)
    out = {}
    if where.time is not None:
        out["time"] = str(plot_time(where.time, fig_dir / DIAGNOSIS_FIGURES["where_time"], title))
    if where.state is not None:
        out["state"] = str(plot_state(where.state, fig_dir / DIAGNOSIS_FIGURES["where_state"], title))
    if where.latent is not None:
        out["latent"] = str(plot_latent(where.latent, fig_dir / DIAGNOSIS_FIGURES["where_latent"], title))
    if where.image is not None:
        out["image"] = str(plot_image(where.image, fig_dir / DIAGNOSIS_FIGURES["where_image"], title))
    return out

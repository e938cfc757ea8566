"""What the geometry of the force transport predicts, measured on a trained model.

Paper §3.4 (Eq. 9), §4.5 and Fig. 7: a force ``f`` applied at an image point
``x`` enters the latent dynamics as ``kappa J_bar(x)^T f`` with
``J_bar(x) = sum_i w_i(x) J_i`` the brush-weighted constant Jacobians. Four
consequences can be checked without any force measurement:

* **background**: on image regions that never move in the video the decoder's
  primitives should not move with ``q`` either, so a force there moves nothing:
  the loaded-equilibrium displacement ``|dq|`` at every static point is at
  least ``50x`` below the typical on-object value;
* **linearity**: at a fixed application point the generalized forces of two
  forces add exactly (the pull-back is linear); the loaded equilibria add to
  first order in the force (reported, the potential is not quadratic);
* **kernel**: a force orthogonal to every column of ``J_bar(x)`` transports to
  zero;
* **lever arm**: on a rotating body the response grows linearly with the
  distance from the pivot and flips sign across it (:func:`lever_profile`,
  used where the pivot is known, e.g. the synthetic pendulums).

Where the object is comes from the video, not from the model under test: the
per-pixel temporal standard deviation of the clip marks moving pixels
(``>= moving_frac * max``) and static ones (``<= static_factor`` times the
noise floor, at least ``3 sigma`` px away from any pixel that changes, so the
brush cannot reach anything that moves).

:func:`run_force_checks` returns a JSON-ready dict; :func:`plot_force_checks`
draws the figure (``python -m lagsplat forces system=<name>`` writes both).
Units: pixels of the training resolution, forces in pixel-force units
(``kappa = 1``), latent ``q`` in whitened chart units.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from lagsplat.forces.transport import ForceTransport
from lagsplat.motion import motion_masks
from lagsplat.models.lagrangian import Lagrangian

__all__ = ["ForceCheckConfig", "motion_masks", "object_at_rest", "run_force_checks", "lever_profile", "plot_force_checks", "public_result"]


@dataclass
class ForceCheckConfig:
    """Settings of :func:`run_force_checks` (``conf/config.yaml``, group ``forces``).

    Attributes:
        sigma: brush radius, pixels.
        min_transmittance: the visible brush's front-surface threshold ``tau``
            (:mod:`lagsplat.forces.transport`; 0: every composited primitive).
        grid: spacing of the probe points, pixels.
        moving_frac: a pixel moves if its temporal std is at least this share of the largest.
        static_factor: a pixel is static if its temporal std is at most this multiple of the noise floor (10th percentile).
        target_dq: the probe force is scaled so the largest on-object ``|dq|`` is about this (chart units).
        background_ratio: the background check passes when ``median on-object |dq| / max background |dq|`` reaches it.
        seed: seed of the random force pairs of the linearity check.
    """

    sigma: float = 1.5
    min_transmittance: float = 0.0
    grid: int = 2
    moving_frac: float = 0.25
    static_factor: float = 1.5
    target_dq: float = 0.5
    background_ratio: float = 50.0
    seed: int = 0


def _grid_points(mask: np.ndarray, step: int) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    keep = (ys % step == 0) & (xs % step == 0)
    return np.stack([xs[keep] + 0.5, ys[keep] + 0.5], 1).astype(np.float32)


def _strongest_direction(Jb: torch.Tensor) -> torch.Tensor:
    """Unit image direction ``[P,2]`` with the largest ``|J_bar^T f|`` (top left-singular vector)."""
    U, S, _ = torch.linalg.svd(Jb.double())
    return U[:, :, 0].float()


def _equilibria(model: Lagrangian, f_lat: torch.Tensor, q_rest: torch.Tensor) -> torch.Tensor:
    """Loaded equilibria ``[P,d]`` for generalized forces ``[P,d]`` (batched damped Newton)."""
    out = []
    for s in range(0, len(f_lat), 256):
        fb = f_lat[s : s + 256]
        out.append(model.loaded_equilibrium(fb, q0=q_rest.expand(len(fb), -1)).float())
    return torch.cat(out) if out else f_lat.new_zeros(0, f_lat.shape[1])


def object_at_rest(images: np.ndarray, rest_image: np.ndarray, moving: np.ndarray, threshold: float = 0.1) -> np.ndarray:
    """Pixels of the object in its rest pose, ``[H,W]`` bool.

    Moving pixels where the rest render differs from the clip's temporal median
    (the scene without the object, where the object keeps moving) by more than
    ``threshold`` (intensity in [0, 1], channel mean). Falls back to ``moving``
    when that leaves fewer than 10 pixels.
    """
    med = np.median(images, axis=0).astype(np.float32)
    diff = np.abs(rest_image.astype(np.float32) - med).mean(-1) / 255.0
    obj = moving & (diff > threshold)
    return obj if obj.sum() >= 10 else moving


def run_force_checks(
    model: Lagrangian,
    transport: ForceTransport,
    images: np.ndarray,
    rest_image: np.ndarray | None = None,
    cfg: ForceCheckConfig | None = None,
    n_linearity: int = 24,
) -> dict[str, Any]:
    """Background, linearity and kernel checks of the force transport on a trained model.

    Args:
        model: the trained Lagrangian (``q_rest``, ``loaded_equilibrium``).
        transport: its :class:`~lagsplat.forces.transport.ForceTransport`.
        images: uint8 ``[T,H,W,3]`` frames of the clip (where things move).
        rest_image: uint8 ``[H,W,3]`` decoder render at rest: the on-object
            points are where it shows the object (:func:`object_at_rest`);
            without it, every moving pixel.
        cfg: :class:`ForceCheckConfig`.
        n_linearity: on-object points used by the linearity and kernel checks.

    Returns:
        Dict with ``background`` (``ratio`` = median on-object ``|dq|`` / max
        background ``|dq|``, ``passed``, the worst point), ``linearity``
        (``f_lat_rel_err`` = max ``|g(f1+f2) - g(f1) - g(f2)| / (|g(f1)| + |g(f2)|)``
        over points, float64, exact up to rounding; ``equilibrium_rel_err`` the
        same for loaded-equilibrium displacements, first order), ``kernel``
        (``rel`` = max ``|J_bar^T f_perp| / |J_bar^T f_par|``), ``force_px``
        (probe force magnitude) and the maps for :func:`plot_force_checks`.

    Raises:
        ValueError: if the masks leave no on-object or no background point.
    """
    cfg = cfg or ForceCheckConfig()
    moving, static, std = motion_masks(images, cfg.sigma, cfg.moving_frac, cfg.static_factor)
    on = moving if rest_image is None else object_at_rest(images, rest_image, moving)
    obj = _grid_points(on, 1)
    bg = _grid_points(static, cfg.grid)
    if len(obj) == 0 or len(bg) == 0:
        raise ValueError(f"need on-object and background points, got {len(obj)} and {len(bg)}")
    q0 = model.q_rest.detach()[None].float()
    J_obj = transport.brush_jacobian(q0, torch.from_numpy(obj), cfg.sigma)
    J_bg = transport.brush_jacobian(q0, torch.from_numpy(bg), cfg.sigma)

    # probe force: the unit force of largest effect at each point, scaled so the
    # largest on-object displacement is about target_dq (first-order estimate)
    e_obj, e_bg = _strongest_direction(J_obj), _strongest_direction(J_bg)
    f_obj = torch.einsum("pid,pi->pd", J_obj, e_obj)
    K = model.potential_hessian(q0)[0].float()
    dq_lin = torch.linalg.solve(K, f_obj.T).T.norm(dim=1)
    F = cfg.target_dq / max(float(dq_lin.max()), 1e-12)
    dq_obj = (_equilibria(model, F * f_obj, q0) - q0).norm(dim=1)
    f_bg = torch.einsum("pid,pi->pd", J_bg, e_bg)
    dq_bg = (_equilibria(model, F * f_bg, q0) - q0).norm(dim=1)
    on = float(dq_obj.median())
    worst = int(dq_bg.argmax())
    off = float(dq_bg[worst])
    ratio = on / off if off > 0 else None  # None: no background point moves at all

    # linearity and kernel at on-object points of large response
    rng = np.random.default_rng(cfg.seed)
    order = torch.argsort(dq_obj, descending=True)[: max(1, n_linearity)]
    lin_f, lin_q, ker = [], [], []
    for i in order.tolist():
        J = J_obj[i : i + 1]
        f1 = torch.from_numpy(rng.normal(size=(1, 2)).astype(np.float32))
        f2 = torch.from_numpy(rng.normal(size=(1, 2)).astype(np.float32))
        for f in (f1, f2):
            f *= F / float(f.norm())
        g = lambda f: torch.einsum("bid,bi->bd", J.double(), f.double())  # noqa: E731
        g1, g2, g12 = g(f1), g(f2), g(f1.double() + f2.double())
        # relative to |g1| + |g2|: the sum may nearly cancel
        lin_f.append(float((g12 - g1 - g2).norm() / (g1.norm() + g2.norm()).clamp_min(1e-300)))
        # first order: halve the forces so the combined one stays in range
        q1, q2, q12 = (_equilibria(model, 0.5 * x.float(), q0) - q0 for x in (g1, g2, g12))
        lin_q.append(float((q12 - q1 - q2).norm() / (q1.norm() + q2.norm()).clamp_min(1e-30)))
        # kernel: the image direction(s) J^T annihilates (the smallest left-singular vector)
        U, S, _ = torch.linalg.svd(J[0].double())
        f_perp = U[:, -1].float()[None] * F
        f_par = U[:, 0].float()[None] * F
        ker.append(float(g(f_perp).norm() / g(f_par).norm().clamp_min(1e-300)))
    bgp = bg[worst]
    return {
        "sigma_px": cfg.sigma,
        "force_px": F,
        "n_object_points": int(len(obj)),
        "n_background_points": int(len(bg)),
        "background": {
            "on_object_median_dq": on,
            "on_object_max_dq": float(dq_obj.max()),
            "background_max_dq": off,
            "background_median_dq": float(dq_bg.median()),
            "worst_point_px": [float(bgp[0]), float(bgp[1])],
            "ratio": ratio,
            "required_ratio": cfg.background_ratio,
            "passed": bool(ratio is None or ratio >= cfg.background_ratio),
        },
        "linearity": {
            "n_points": len(lin_f),
            "f_lat_rel_err": max(lin_f),
            "equilibrium_rel_err": max(lin_q),
            "equilibrium_rel_err_median": float(np.median(lin_q)),
            "passed": bool(max(lin_f) < 1e-9),
        },
        "kernel": {"n_points": len(ker), "rel": max(ker), "passed": bool(max(ker) < 1e-6)},
        "_maps": {
            "object": on,
            "moving": moving,
            "static": static,
            "obj": obj,
            "bg": bg,
            "dq_obj": dq_obj.numpy(),
            "dq_bg": dq_bg.numpy(),
        },
    }


def lever_profile(
    model: Lagrangian,
    transport: ForceTransport,
    pivot: tuple[float, float],
    direction: tuple[float, float],
    radii: np.ndarray,
    force: tuple[float, float],
    sigma: float = 1.5,
) -> dict[str, np.ndarray]:
    """Response to one force applied at points along a line through a pivot.

    Points ``pivot + r * direction`` for each ``r`` in ``radii`` (px, signed:
    negative radii lie beyond the pivot). For ``d = 1`` the generalized force
    ``J_bar(x)^T f`` of a rigid rotation is ``r`` times a constant, so it grows
    linearly with the lever arm and changes sign at the pivot.

    Returns:
        ``{"r": [n], "f_lat": [n,d], "dq": [n,d]}`` (``dq``: loaded-equilibrium
        displacement from rest).
    """
    q0 = model.q_rest.detach()[None].float()
    p = np.asarray(pivot, np.float32)[None] + np.asarray(radii, np.float32)[:, None] * np.asarray(direction, np.float32)[None]
    Jb = transport.brush_jacobian(q0, torch.from_numpy(p), sigma)
    f = torch.tensor(force, dtype=torch.float32)
    f_lat = torch.einsum("pid,i->pd", Jb, f)
    dq = _equilibria(model, f_lat, q0) - q0
    return {"r": np.asarray(radii, float), "points": p, "f_lat": f_lat.numpy(), "dq": dq.numpy()}


def plot_force_checks(result: dict[str, Any], rest_image: np.ndarray, out_path, title: str = "", lever: dict | None = None) -> None:
    """Figure in the spirit of the paper's Fig. 7: where forces act, and the checks.

    Panels: (a) rest render with the loaded-equilibrium response ``|dq|`` at
    every probe point (log colour; background points as dots), the worst
    background point circled; (b) ``|dq|`` distributions on the object and on
    the background with the required 50x gap; (c) the lever-arm profile when
    given (:func:`lever_profile`), else the linearity and kernel numbers.

    Args:
        result: output of :func:`run_force_checks`.
        rest_image: uint8 ``[H,W,3]`` decoder render at rest.
        out_path: PNG path (written atomically).
        title: figure title.
        lever: optional :func:`lever_profile` output.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from lagsplat.io.atomic import atomic_write

    m = result["_maps"]
    fig, ax = plt.subplots(1, 3, figsize=(13.5, 4.2), gridspec_kw={"width_ratios": [1.3, 1, 1]})
    H, W = rest_image.shape[:2]
    ax[0].imshow(rest_image, extent=(0, W, H, 0))
    vals = np.concatenate([m["dq_obj"], m["dq_bg"]])
    lo = max(float(vals[vals > 0].min()) if (vals > 0).any() else 1e-12, 1e-6 * float(vals.max()))
    norm = LogNorm(vmin=lo, vmax=max(float(vals.max()), lo * 10))
    sc = ax[0].scatter(m["obj"][:, 0], m["obj"][:, 1], c=np.clip(m["dq_obj"], lo, None), s=6, cmap="magma", norm=norm, marker="s")
    ax[0].scatter(m["bg"][:, 0], m["bg"][:, 1], c=np.clip(m["dq_bg"], lo, None), s=3, cmap="magma", norm=norm)
    wp = result["background"]["worst_point_px"]
    ax[0].add_patch(plt.Circle(wp, 3 * result["sigma_px"], fill=False, color="cyan", lw=1.2))
    fig.colorbar(sc, ax=ax[0], fraction=0.046, label="|dq| under the probe force (chart units)")
    ax[0].set_title("(a) response to a push at each point")
    ax[0].set_axis_off()

    b = result["background"]
    bins = np.logspace(np.log10(lo), np.log10(norm.vmax), 40)
    ax[1].hist(np.clip(m["dq_obj"], lo, None), bins=bins, alpha=0.7, label=f"object ({len(m['dq_obj'])} pts)")
    ax[1].hist(np.clip(m["dq_bg"], lo, None), bins=bins, alpha=0.7, label=f"static background ({len(m['dq_bg'])} pts)")
    ax[1].axvline(b["on_object_median_dq"], color="C0", ls="--")
    ax[1].axvline(b["on_object_median_dq"] / b["required_ratio"], color="k", ls=":", label=f"median / {b['required_ratio']:g}")
    ax[1].set_xscale("log")
    ax[1].set_xlabel("|dq| (chart units)")
    gap = "exactly still" if b["ratio"] is None else f"{b['ratio']:.0f}x below"
    ax[1].set_title(f"(b) background: {gap} ({'pass' if b['passed'] else 'FAIL'})")
    ax[1].legend(fontsize=8)

    lin, ker = result["linearity"], result["kernel"]
    if lever is not None:
        r, fl = lever["r"], lever["f_lat"][:, 0]
        ax[2].plot(r, fl, "o-", ms=3, label="J_bar(x)^T f")
        A = np.stack([r, np.ones_like(r)], 1)
        coef, *_ = np.linalg.lstsq(A, fl, rcond=None)
        ax[2].plot(r, A @ coef, "k:", label=f"line, slope {coef[0]:.3g}")
        ax[2].axvline(0, color="grey", lw=0.8)
        ax[2].axhline(0, color="grey", lw=0.8)
        ax[2].set_xlabel("radius from the pivot (px; < 0 beyond it)")
        ax[2].set_ylabel("generalized force")
        ax[2].legend(fontsize=8, loc="lower right")
        ax[2].set_title("(c) lever arm and sign flip")
    else:
        ax[2].set_axis_off()
        ax[2].set_title("(c) linearity and kernel")
    ax[2].text(
        0.02,
        0.98 if lever is not None else 0.02,
        f"J^T f additivity: {lin['f_lat_rel_err']:.1e}\nequilibria, first order: {lin['equilibrium_rel_err']:.1e}\n"
        f"kernel |J^T f_perp|/|J^T f_par|: {ker['rel']:.1e}",
        transform=ax[2].transAxes,
        fontsize=8,
        va="top" if lever is not None else "bottom",
        family="monospace",
    )
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_write(out_path) as tmp:
        fig.savefig(tmp, dpi=130, format="png")
    plt.close(fig)


def public_result(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` without its plotting maps (JSON-ready)."""
    return {k: v for k, v in result.items() if not k.startswith("_")}

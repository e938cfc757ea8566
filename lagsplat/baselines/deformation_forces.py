"""Forces through either decoder, against the rigid-body truth of the synthetic pendulum (paper §3.4, App. B).

A force ``f`` (px, image axes, ``y`` down) applied to the brushed material
enters the latent dynamics as ``kappa sum_i w_i J_i^T f`` (paper Eq. 9). The
conditioned decoder's ``J_i`` are constant
(:class:`~lagsplat.forces.transport.ForceTransport`); the deformation decoder's depend
on the state (:class:`StateTransport`, ``J_i(q)`` at the current state), so
its loaded equilibrium is the fixed point of
``q = q_eq(kappa sum_i w_i J_i(q)^T f)`` (:func:`loaded_state`; for constant
``J_i`` it is reached in one step).

The truth (the pendulum of :mod:`lagsplat.synth.pendulum`, pivot at
``(W/2, PIVOT_Y H)``, rod ``ROD_LENGTH H``): a static force ``F`` at radius
``r`` (fraction of the rod) holds it at the angle ``theta`` with
``sin(theta) = r (Fx cos(theta) - Fy sin(theta))`` (force unit ``I w0^2``),
which moves that point by ``r L (sin theta, cos theta - 1)`` px. As in
``benchmarks/force_truth.py``, ``kappa`` is calibrated on the first force
and the others are scored by the direction (deg) and magnitude (%) of the
displacement, read two ways: the application point ``sum_i w_i mu_i(q)`` of
the frozen selection, and the chart read-out (the angle ``theta(q_eq)`` of a
cubic fitted to the encoded training frames against their true angle).
Forces whose material the decoder saw moving less than ``min_motion`` px
(rms over the training states) are reported but not scored.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.optimize import brentq
from torch import Tensor

from lagsplat.forces.transport import ForceTransport, Selection
from lagsplat.io.clip import TRAIN
from lagsplat.synth.pendulum import PIVOT_Y, ROD_LENGTH

__all__ = ["StateTransport", "transport_of", "loaded_state", "true_angle", "CASES", "force_truth"]

#: (radius as a fraction of the rod, force (Fx, Fy)); the first calibrates kappa (those of benchmarks/force_truth.py).
CASES = [
    (1.0, (0.06, 0.0)), (1.0, (0.12, 0.0)), (1.0, (-0.09, 0.0)), (1.0, (0.05, 0.02)), (1.0, (-0.10, -0.03)), (1.0, (0.04, 0.0)),
    (0.75, (0.12, 0.0)), (0.75, (-0.10, 0.03)), (0.5, (0.16, 0.0)), (0.5, (-0.20, -0.05)), (-0.12, (0.60, 0.0)), (1.0, (0.08, 0.08)),
]  # fmt: skip


class StateTransport(ForceTransport):
    """:class:`~lagsplat.forces.transport.ForceTransport` of the deformation decoder: positions, footprints and
    Jacobians read at the state (paper App. B), all in pixels of the training resolution and whitened ``q``.

    Args:
        ae: a Stage-1 autoencoder whose decoder is a :class:`~lagsplat.models.deformation.DeformationGaussians`.
        chart: its chart (``W_inv``, ``mean``).
        brush, min_transmittance: as :class:`~lagsplat.forces.transport.ForceTransport`.

    Raises:
        ValueError: for another decoder family.
    """

    def __init__(self, ae, chart, brush: str = "visible", min_transmittance: float = 0.0) -> None:
        dec = ae.decoder
        if dec.kind != "deformation":
            raise ValueError(f"StateTransport needs the deformation decoder, got {dec.kind!r} (use ForceTransport.from_autoencoder)")
        with torch.no_grad():
            g = dec.geometry()
        W_inv, mean = (torch.as_tensor(np.asarray(x), dtype=torch.float32) for x in (chart.W_inv, chart.mean))
        K, d = dec.K, dec.d
        super().__init__(torch.zeros(K, 2), torch.zeros(K, 2, d), g.alpha.clone(), g.mu_q.clone(), g.L_qq.clone(), W_inv, mean,
                         None, brush, (ae.height, ae.width), min_transmittance)  # fmt: skip
        self.ae = ae

    @torch.no_grad()
    def means(self, q: Tensor) -> Tensor:
        """Primitive positions ``mu_i(q) [B,K,2]`` px (the network at the state)."""
        out = [self.ae.decoder.state_kinematics(q[i : i + 64], self.W_inv, self.mean, self.ae.height, self.ae.width)[0] for i in range(0, len(q), 64)]
        return torch.cat(out)

    def opacity(self, q: Tensor) -> Tensor:
        """Rendered opacity ``alpha_i [B,K]``: no latent gate."""
        return self.alpha[None].expand(len(q), -1)

    @torch.no_grad()
    def jacobians(self, q: Tensor) -> Tensor:
        """``J_i(q) [K,2,d]`` px per unit ``q`` at one state ``q [1,d]``."""
        return self.ae.decoder.state_kinematics(q.reshape(1, -1), self.W_inv, self.mean, self.ae.height, self.ae.width)[1][0]

    @torch.no_grad()
    def select(self, q: Tensor, x: Tensor, sigma: float) -> Selection:
        """As :meth:`ForceTransport.select`, with each state's footprints ``Sigma_i(q)`` (px^2)."""
        rows = []
        for b in range(len(q)):
            _, _, g = self.ae.decoder.condition(q[b : b + 1] @ self.W_inv + self.mean)
            scale = torch.tensor([float(self.ae.width), float(self.ae.height)])
            self.cov = g.cov[0] * scale[:, None] * scale[None, :]
            rows.append(super().select(q[b : b + 1], x[b : b + 1], sigma).weights)
        return Selection(torch.cat(rows))

    def observed_motion(self, sel: Selection, q: Tensor) -> Tensor:
        """Rms displacement ``[B]`` px of the selected material over the states ``q [T,d]`` (its own curved path)."""
        p = torch.einsum("bk,tki->bti", sel.weights, self.means(q))
        return (p - p.mean(1, keepdim=True)).pow(2).sum(-1).mean(-1).sqrt()


def transport_of(ae, chart, brush: str = "visible", min_transmittance: float = 0.0) -> ForceTransport:
    """The force transport of either decoder family (constant or state-dependent Jacobians)."""
    if ae.decoder.kind == "deformation":
        return StateTransport(ae, chart, brush, min_transmittance)
    return ForceTransport.from_autoencoder(ae, chart, brush, min_transmittance)


def _pullback(tr: ForceTransport, sel: Selection, f: Tensor, q: Tensor) -> Tensor:
    """``sum_i w_i J_i(q)^T f [1,d]`` (``J_i`` at ``q [1,d]`` for a :class:`StateTransport`)."""
    if isinstance(tr, StateTransport):
        return torch.einsum("bk,kid,bi->bd", sel.weights, tr.jacobians(q), f)
    return tr.pullback(sel, f)


def loaded_state(model, tr: ForceTransport, sel: Selection, f: Tensor, kappa: float, q0: Tensor, iters: int = 60, tol: float = 1e-6) -> Tensor:
    """Loaded equilibrium ``q [1,d]`` under the force ``f [1,2]`` with the Jacobians at the current state.

    Relaxed fixed-point iteration ``q <- (q + q_eq(kappa sum_i w_i J_i(q)^T f)) / 2``, from ``q0``, until
    the step is below ``tol`` (chart units); exact in one step for constant ``J_i``.
    """
    q = model.loaded_equilibrium(kappa * _pullback(tr, sel, f, q0), q0=q0).float()
    if not isinstance(tr, StateTransport):
        return q
    for _ in range(iters):
        q_new = model.loaded_equilibrium(kappa * _pullback(tr, sel, f, q), q0=q).float()
        step = float((q_new - q).abs().max())
        q = 0.5 * (q + q_new)
        if step < tol:
            break
    return q


def true_angle(F, r: float) -> float:
    """Static angle (rad) of the pendulum under force ``F`` (units ``I w0^2``) at radius ``r`` (fraction of the rod)."""
    g = lambda th: math.sin(th) - r * (F[0] * math.cos(th) - F[1] * math.sin(th))  # noqa: E731
    return brentq(g, -math.pi / 2 + 1e-9, math.pi / 2 - 1e-9)


def _arc(theta: float, r: float, L_px: float) -> np.ndarray:
    """Displacement (px) of the rod point at radius ``r`` swung from rest to ``theta`` (rad)."""
    return r * L_px * np.array([math.sin(theta), math.cos(theta) - 1.0])


def _score(d_true: np.ndarray, d_pred: np.ndarray) -> tuple[float, float]:
    """Direction error (deg, signed) and magnitude error (%) of a predicted displacement."""
    ang = math.degrees(math.atan2(d_true[0] * d_pred[1] - d_true[1] * d_pred[0], float(d_true @ d_pred)))
    return ang, 100.0 * (float(np.linalg.norm(d_pred)) / float(np.linalg.norm(d_true)) - 1.0)


def _calibrate(readout, target: float, bracket=(1e-6, 1e6)) -> float:
    """``kappa`` with ``readout(kappa) = target`` (px), by bisection in ``log kappa``."""
    gap = lambda lk: readout(math.exp(lk)) - target  # noqa: E731
    lo, hi = math.log(bracket[0]), math.log(bracket[1])
    if np.sign(gap(lo)) == np.sign(gap(hi)):
        raise ValueError(f"a displacement of {target:.3g} px is not reached for kappa in {bracket}")
    return math.exp(brentq(gap, lo, hi, xtol=1e-8, rtol=1e-8))


def force_truth(ae, chart, model, clip, sigma: float = 1.5, min_transmittance: float = 0.0, min_motion: float = 1.0,
                max_deg: float = 5.0, max_pct: float = 10.0) -> dict:  # fmt: skip
    """Push the decoder with the forces of :data:`CASES` and score the loaded equilibria against the truth.

    Args:
        ae, chart, model: the Stage-1 autoencoder, its chart and the Stage-2 Lagrangian trained on it.
        clip: the synthetic pendulum clip (``meta["theta"]``, rad per frame).
        sigma: brush radius, px; min_transmittance: the visible brush's threshold (:mod:`lagsplat.forces.transport`).
        min_motion: a force is scored only where the material was seen moving this much (rms px).
        max_deg, max_pct: tolerances counted in the summary.

    Returns:
        ``kappa`` (application point, chart read-out), ``rows`` (per force: radius, force, true angle and
        displacement, each read-out's displacement and errors, ``seen_px``, ``scored``) and ``summary``
        (per read-out, over the scored forces after the calibration: max and median ``|direction error|``,
        ``|magnitude error|``, and how many are within the tolerances).

    Raises:
        ValueError: if the clip has no true angles.
    """
    if "theta" not in clip.meta:
        raise ValueError("the force truth needs a synthetic pendulum clip (clip.meta['theta'])")
    tr = transport_of(ae, chart, "visible", min_transmittance)
    train = clip.split == TRAIN
    q_train = np.asarray(chart.q, float)[train]
    theta_of_q = np.poly1d(np.polyfit(q_train[:, 0], np.asarray(clip.meta["theta"], float)[train], 3))
    H, W = ae.height, ae.width
    L_px, pivot = ROD_LENGTH * H, np.array([W / 2.0, PIVOT_Y * H])
    q0 = model.q_rest.detach()[None].float()
    th0 = float(theta_of_q(float(q0[0, 0])))
    qt = torch.as_tensor(q_train, dtype=torch.float32)
    setups = []
    for r, F in CASES:
        F = np.asarray(F, float)
        sel = tr.select(q0, torch.as_tensor((pivot + [0.0, r * L_px])[None], dtype=torch.float32), sigma)
        th = true_angle(F, r)
        setups.append((r, F, sel, th, _arc(th, r, L_px), float(tr.observed_motion(sel, qt)[0])))
    f_t = lambda F: torch.as_tensor(F[None], dtype=torch.float32)  # noqa: E731
    point = lambda q, sel: (tr.application_point(q, sel) - tr.application_point(q0, sel))[0].numpy().astype(float)  # noqa: E731
    chart_disp = lambda q, r: _arc(float(theta_of_q(float(q[0, 0]))) - th0, r, L_px)  # noqa: E731
    r0, F0, sel0, _, d0, _ = setups[0]
    target = float(np.linalg.norm(d0))
    k_point = _calibrate(lambda k: float(np.linalg.norm(point(loaded_state(model, tr, sel0, f_t(F0), k, q0), sel0))), target)
    k_chart = _calibrate(lambda k: float(np.linalg.norm(chart_disp(loaded_state(model, tr, sel0, f_t(F0), k, q0), r0))), target)
    rows = []
    for i, (r, F, sel, th, d_true, seen) in enumerate(setups):
        dp = point(loaded_state(model, tr, sel, f_t(F), k_point, q0), sel)
        dc = chart_disp(loaded_state(model, tr, sel, f_t(F), k_chart, q0), r)
        (ap, mp), (ac, mc) = _score(d_true, dp), _score(d_true, dc)
        rows.append({"radius": r, "force": F.tolist(), "true_angle_deg": math.degrees(th), "true_disp_px": d_true.tolist(),
                     "point_disp_px": dp.tolist(), "point_dir_err_deg": ap, "point_mag_err_pct": mp, "chart_disp_px": dc.tolist(),
                     "chart_dir_err_deg": ac, "chart_mag_err_pct": mc, "seen_px": seen, "calibration": i == 0,
                     "scored": i > 0 and seen >= min_motion})  # fmt: skip
    summary = {}
    test = [r for r in rows if r["scored"]]
    for name in ("point", "chart"):
        dirs = np.abs([r[f"{name}_dir_err_deg"] for r in test])
        mags = np.abs([r[f"{name}_mag_err_pct"] for r in test])
        summary[name] = {
            "n_scored": len(test),
            "max_abs_dir_err_deg": float(dirs.max()) if len(test) else None, "median_abs_dir_err_deg": float(np.median(dirs)) if len(test) else None,
            "max_abs_mag_err_pct": float(mags.max()) if len(test) else None, "median_abs_mag_err_pct": float(np.median(mags)) if len(test) else None,
            "n_within": int(((dirs <= max_deg) & (mags <= max_pct)).sum()),
        }  # fmt: skip
    return {"kappa": {"point": k_point, "chart": k_chart}, "sigma_px": sigma, "min_transmittance": min_transmittance, "min_motion_px": min_motion,
            "tolerance": {"deg": max_deg, "pct": max_pct}, "rows": rows, "summary": summary}  # fmt: skip

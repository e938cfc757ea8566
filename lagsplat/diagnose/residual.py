"""Residual generalized force of a fitted model on an encoded trajectory.

What the identified Lagrangian leaves unexplained, in the units of the
Euler-Lagrange equation (paper Eq. 7): along the encoded trajectory,

    r(t) = M(q) (qddot_obs - a_model(q, qdot, u)),

the generalized force an unmodelled effect must supply for the model to
reproduce the observed acceleration. Every candidate effect of
:mod:`lagsplat.diagnose.effects` is a generalized force ``f_eff(q, qdot, t, u)``
that enters the right-hand side of Eq. 7 additively, so ``r`` is what a
candidate is fitted to.

Differentiation
---------------
The chart ``q`` is noisy, so ``qdot`` and ``qddot`` come from Gaussian
derivative filters (``scipy.ndimage.gaussian_filter1d`` of order 1, 2, 3 with
standard deviation ``sigma`` frames) rather than from finite differences.
Gaussian filters (rather than Savitzky-Golay ones) are used because they
commute with differentiation, ``G'' * q = G * q''``: with ``G`` the smoothing,
the observed acceleration is ``G * (a_model + f_eff / M)`` of the *true*
state. The same smoothing is therefore applied to what is compared with it:
the model's acceleration and every candidate feature are evaluated on the
de-blurred state and then smoothed by ``G`` (:meth:`Residual.features <lagsplat.diagnose.residual_data.Residual.features>`), so a
sharp effect (a Coulomb switch, an impact) is compared with its own smoothed
image. De-blurring is the first-order inverse of the heat kernel,
``q ~ G*q - (sigma dt)^2 / 2 G*q''`` (likewise for ``qdot``), which removes the
amplitude loss ``exp(-(w sigma dt)^2 / 2)`` to first order before a nonlinear
feature is evaluated (an end stop's bounce is too sharp for a first-order
inverse: it reads the chart's own positions, :attr:`SegmentState.q_raw <lagsplat.diagnose.residual_data.SegmentState.q_raw>`,
whose noise is small beside the penetration). For the model, what de-blurring and re-smoothing leave
of the state is removed through the model's local linearisation, which makes
the comparison exact for a linear model whatever the spectrum of the motion
and of the input (:func:`~lagsplat.diagnose.model_response.smoothed_model_acceleration`). Kernels are truncated at 6 sigma (at 4 sigma the
truncation alone leaves a 0.1 % error in ``G''``).

Segments are padded by odd reflection about their end samples (continuous
value and slope) before filtering, and ``ceil(3 sigma)`` samples are dropped at
each end of the residual where the padding still shows.

Smoothing width
---------------
The default ``sigma = clip(period / 12, 2, 6)`` frames keeps the sharp
waveform an end stop or a stiffening spring puts on the motion (the 3rd
harmonic passes at ``exp(-(3 w sigma dt)^2 / 2) = 0.29``). It also puts the
differentiated chart noise, whose spectrum ``~ w^4 exp(-(w sigma dt)^2)``
peaks at ``w = sqrt(2) / (sigma dt) = 2.7 w0``, right at those harmonics: most
of the residual's variance then lies where a slow effect has no power. The
effects that no Lagrangian of the paper's class can produce (paper §3.3 allows
only the Rayleigh dissipation ``1/2 qdot^T C(q) qdot``; §5 names what falls
outside) are mostly slow ones: quadratic drag and dry friction differ from the
model's viscous damping only in how the decay rate depends on the amplitude
(hyperbolic or linear envelope instead of exponential), which sits at the
fundamental; a drift, an unlogged force or a hidden mode below the harmonics
are slower still. So every residual also carries :attr:`Residual.wide <lagsplat.diagnose.residual_data.Residual.wide>`, the
same residual at ``wide_factor`` (1.5) times the smoothing, ``period / 8`` by
default, on which :func:`~lagsplat.diagnose.select_effect` fits those
*out-of-class* candidates: the noise variance (``~ sigma^-5``) falls 7.6x,
the fundamental still passes at 0.73 (0.87 at ``period / 12``), and the
features are evaluated on a state de-blurred from less noisy derivatives.
The in-class candidates (end stop, cubic stiffness) keep the sharp residual.
On the blind suite's pendulum clips at 32 x 32 px the change turns quadratic
drag from missed to found while the controls' out-of-class candidates stay
below zero (``benchmarks/diagnosis.py``; the measurement:
``docs/experiments/code_comment_history.md``).

Noise level
-----------
The chart noise ``sigma_q`` (per latent coordinate) is read from the fourth
difference of the raw trajectory, which cancels a smooth signal to
``(w dt)^4`` and multiplies white noise by ``sqrt(70)`` (robust MAD scale).
Its image in the residual is ``sigma_r = |M| sigma_q |g''|_2 / dt^2`` with
``g''`` the discrete second-derivative kernel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter1d

from lagsplat import metrics, timeseries
from lagsplat.diagnose.filters import chart_noise, kernel_norm, pad_odd
from lagsplat.diagnose.model_response import (
    AccelerationModel,
    model_acceleration,
    smoothed_model_acceleration,
)
from lagsplat.diagnose.residual_data import Residual, SegmentState

#: Default residual smoothing: ``sigma = period / SIGMA_PER_PERIOD`` frames (clipped to ``[2, 6]``), ``period`` the dominant one in frames.
SIGMA_PER_PERIOD = 12.0
#: The out-of-class candidates' residual is smoothed this many times wider (``period / 8`` by default).
WIDE_FACTOR = 1.5

__all__ = [
    "SIGMA_PER_PERIOD",
    "WIDE_FACTOR",
    "chart_segments",
    "residual_force",
    "residual_from_chart",
]

#: The per-sample columns a segment contributes to the residual.
_COLUMNS = ("t", "q", "qd", "qdd", "a", "M", "u", "seg", "ep")


def _dominant_frequency(segs: Sequence[np.ndarray], dt: float, G: np.ndarray) -> float:
    longest = max(segs, key=len)
    e = metrics.top_direction(G)
    try:
        return float(timeseries.spectral_peak_frequency(longest @ e, dt))
    except ValueError:
        return float("nan")


def _checked_segments(q_segments: Sequence[np.ndarray], G: np.ndarray | None) -> tuple[list[np.ndarray], np.ndarray]:
    """``(segments as float64 [m_k,d], G [d,d])``; raises ``ValueError`` on bad shapes or non-finite values."""
    segs = [np.asarray(s, np.float64) for s in q_segments]
    if not segs or any(s.ndim != 2 for s in segs):
        raise ValueError("q_segments must be a non-empty list of [m,d] arrays")
    d = segs[0].shape[1]
    if any(s.shape[1] != d for s in segs):
        raise ValueError("all q segments must have the same latent dimension d")
    if any(not np.all(np.isfinite(s)) for s in segs):
        raise ValueError("q_segments contain NaN or inf")
    G = np.eye(d) if G is None else np.asarray(G, np.float64)
    if G.shape != (d, d):
        raise ValueError(f"G must be [d,d] = [{d},{d}], got {G.shape}")
    return segs, G


def _times_and_inputs(
    segs: list[np.ndarray], dt: float, t_segments: Sequence[np.ndarray] | None, u_segments: Sequence[np.ndarray] | None
) -> tuple[Sequence[np.ndarray], Sequence[np.ndarray], int]:
    """``(t_segments, u_segments, n_u)`` with the defaults filled in (``dt`` steps continuing across segments; no input)."""
    if t_segments is None:
        t_segments, t0 = [], 0.0
        for s in segs:
            t_segments.append(t0 + dt * np.arange(len(s)))
            t0 += dt * (len(s) + 1)
    n_u = 0 if u_segments is None else int(np.asarray(u_segments[0]).reshape(len(segs[0]), -1).shape[1])
    if u_segments is None:
        u_segments = [np.zeros((len(s), 0)) for s in segs]
    if len(t_segments) != len(segs) or len(u_segments) != len(segs):
        raise ValueError("q_segments, t_segments and u_segments must have the same length")
    return t_segments, u_segments, n_u


def _interpolator(t_raw: np.ndarray, u_raw: np.ndarray):
    """``u_at(t [k]) -> [k,n_u]``: the segment's actuation at any time, linearly interpolated (end values outside)."""

    def u_at(tq: np.ndarray, _t: np.ndarray = t_raw, _u: np.ndarray = u_raw) -> np.ndarray:
        tq = np.asarray(tq, np.float64)
        return np.stack([np.interp(tq, _t, _u[:, j]) for j in range(_u.shape[1])], -1) if _u.shape[1] else np.zeros((len(tq), 0))

    return u_at


def _segment_residual(
    model: Any, q_raw: np.ndarray, t_raw: np.ndarray, u_raw: np.ndarray, ep: int, index: int, dt: float, sigma: float, n_u: int
) -> tuple[SegmentState, dict[str, np.ndarray]]:
    """One segment, padded, differentiated and de-blurred: its :class:`SegmentState` and its kept samples (:data:`_COLUMNS`)."""
    P = int(math.ceil(6 * sigma))
    trim = int(math.ceil(3 * sigma))
    blur = 0.5 * (sigma * dt) ** 2
    qp, Pk = pad_odd(q_raw, P)
    m = len(qp)
    tp = t_raw[0] + dt * (np.arange(m) - Pk)
    tp[Pk : Pk + len(t_raw)] = t_raw
    up = np.concatenate([np.repeat(u_raw[:1], Pk, 0), u_raw, np.repeat(u_raw[-1:], Pk, 0)], 0)

    def filt(order: int, x: np.ndarray = qp) -> np.ndarray:
        return gaussian_filter1d(x, sigma, axis=0, order=order, mode="nearest", truncate=6.0) / dt**order

    q_s, qd_s, qdd_s, qddd_s = filt(0), filt(1), filt(2), filt(3)
    q_t, qd_t = q_s - blur * qdd_s, qd_s - blur * qddd_s
    u_s = gaussian_filter1d(up, sigma, axis=0, mode="nearest", truncate=6.0) if n_u else up
    keep = slice(Pk + trim, Pk + len(q_raw) - trim)
    a_s = smoothed_model_acceleration(model, q_t, qd_t, up if n_u else None, q_s, qd_s, u_s if n_u else None, keep, sigma)
    _, M = model_acceleration(model, q_s[keep], qd_s[keep], u_s[keep] if n_u else None)
    state = SegmentState(index, ep, tp, q_t, qd_t, up, _interpolator(t_raw, u_raw), keep, qp, slice(Pk, Pk + len(q_raw)))
    cols = {"t": tp[keep], "q": q_s[keep], "qd": qd_s[keep], "qdd": qdd_s[keep], "a": a_s, "M": M, "u": u_s[keep],
            "seg": np.full(len(M), index), "ep": np.full(len(M), ep)}  # fmt: skip
    return state, cols


def _residual_on_segments(
    model: Any, segs: list[np.ndarray], t_segments: Sequence[np.ndarray], u_segments: Sequence[np.ndarray], episodes: list[int],
    dt: float, sigma: float, n_u: int, G: np.ndarray, f_dom: float, meta: dict[str, Any] | None,
) -> Residual:
    """The :class:`Residual` of the segments long enough for ``sigma`` (see :func:`residual_force`)."""
    min_len = 2 * int(math.ceil(3 * sigma)) + 8
    noise_q = chart_noise(segs)
    cols: dict[str, list] = {k: [] for k in _COLUMNS}
    states: list[SegmentState] = []
    for q_raw, t_raw, u_raw, ep in zip(segs, t_segments, u_segments, episodes):
        t_raw = np.asarray(t_raw, np.float64)
        u_raw = np.asarray(u_raw, np.float64).reshape(len(q_raw), n_u)
        if len(q_raw) < min_len:
            continue
        if len(t_raw) != len(q_raw):
            raise ValueError(f"a segment has {len(q_raw)} positions but {len(t_raw)} times")
        state, c = _segment_residual(model, q_raw, t_raw, u_raw, ep, len(states), dt, sigma, n_u)
        states.append(state)
        for k in _COLUMNS:
            cols[k].append(c[k])
    if not states:
        raise ValueError(f"no segment is long enough for the residual: need more than {min_len} samples at sigma = {sigma:.1f} frames")
    cat = {k: np.concatenate(v, 0) for k, v in cols.items()}
    M = cat["M"]
    r = np.einsum("nij,nj->ni", M, cat["qdd"] - cat["a"])
    f_model = np.einsum("nij,nj->ni", M, cat["a"])
    s_qdd = noise_q * kernel_norm(sigma, 2) / dt**2
    M_bar = M.mean(0)
    noise_r = np.sqrt((M_bar**2) @ (s_qdd**2))
    return Residual(
        dt=float(dt), sigma=sigma, t=cat["t"], q=cat["q"], qdot=cat["qd"], qddot=cat["qdd"], a_model=cat["a"], M=M,
        r=r, f_model=f_model, u=cat["u"], segment=cat["seg"].astype(int), episode=cat["ep"].astype(int),
        noise_q=noise_q, noise_r=np.maximum(noise_r, 1e-12), G=G, f_dominant_hz=f_dom, spacing=max(1.0, 2.0 * sigma),
        states=states, meta=dict(meta or {}),
    )  # fmt: skip


# ------------------------------------------------------------------ main entry
def residual_force(
    model: AccelerationModel,
    q_segments: Sequence[np.ndarray],
    dt: float,
    t_segments: Sequence[np.ndarray] | None = None,
    u_segments: Sequence[np.ndarray] | None = None,
    episodes: Sequence[int] | None = None,
    G: np.ndarray | None = None,
    sigma: float | None = None,
    meta: dict[str, Any] | None = None,
    wide_factor: float | None = WIDE_FACTOR,
) -> Residual:
    """The residual generalized force ``r = M (qddot - a_model)`` of a model on contiguous trajectories (paper Eq. 7).

    Args:
        model: anything with ``acceleration(q [B,d], qdot [B,d], f_ext=None, u=None) -> [B,d]``
            (torch, e.g. :class:`~lagsplat.models.lagrangian.Lagrangian`) and
            optionally ``mass_matrix(q) -> [B,d,d]`` (identity otherwise).
        q_segments: list of ``[m_k,d]`` encoded (whitened) trajectories, each contiguous.
        dt: frame interval, s.
        t_segments: list of ``[m_k]`` times (s); default ``dt`` steps continuing across segments.
        u_segments: list of ``[m_k,n_u]`` actuation, or ``None`` (no actuation).
        episodes: recording index of each segment (default ``0, 1, ...``).
        G: ``[d,d]`` latent metric (chart ``G_bar``), identity by default.
        sigma: smoothing standard deviation, frames; default
            ``clip(period / 12, 2, 6)`` with the period of the dominant oscillation.
        meta: provenance stored on the result.
        wide_factor: also compute :attr:`Residual.wide <lagsplat.diagnose.residual_data.Residual.wide>`
            at ``wide_factor * sigma`` (``None`` or ``<= 1``: no wide residual); see "Smoothing width"
            in the module docstring.

    Returns:
        The :class:`~lagsplat.diagnose.residual_data.Residual`.

    Raises:
        ValueError: if no segment is long enough (``2 ceil(3 sigma) + 8`` samples), the
            shapes disagree, the trajectory is non-finite or ``dt <= 0``, or
            ``wide_factor`` is not a finite number.
    """
    if not (math.isfinite(float(dt)) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    if wide_factor is not None and not math.isfinite(float(wide_factor)):
        raise ValueError(f"wide_factor must be a finite number or None, got {wide_factor!r}")
    args = (model, q_segments, dt, t_segments, u_segments, episodes, G)
    segs, G = _checked_segments(q_segments, G)
    t_segments, u_segments, n_u = _times_and_inputs(segs, dt, t_segments, u_segments)
    episodes = list(range(len(segs))) if episodes is None else [int(e) for e in episodes]
    f_dom = _dominant_frequency(segs, dt, G)
    if sigma is None:
        period = 1.0 / (f_dom * dt) if math.isfinite(f_dom) and f_dom > 0 else 24.0
        sigma = float(np.clip(period / SIGMA_PER_PERIOD, 2.0, 6.0))
    sigma = float(sigma)
    if not (sigma > 0):
        raise ValueError(f"sigma must be positive, got {sigma!r}")
    out = _residual_on_segments(model, segs, t_segments, u_segments, episodes, dt, sigma, n_u, G, f_dom, meta)
    if wide_factor is not None and wide_factor > 1.0:
        try:
            out.wide = residual_force(*args, sigma=sigma * float(wide_factor), meta=meta, wide_factor=None)
        except ValueError:  # no segment long enough for the wider kernel: the out-of-class candidates use this one
            out.wide = None
    return out


def chart_segments(chart: Any, which: int | None) -> list[np.ndarray]:
    """Index arrays of the chart's contiguous segments with split ``which`` (``0`` training, ``1`` held-out), or of
    every frame split by episode only (``None``)."""
    from lagsplat.io.clip import segments as split_segments

    if which is None:
        return split_segments(np.zeros(len(chart.t), np.int8), 0, chart.episode)
    return chart.segments(int(which))


def residual_from_chart(
    model: AccelerationModel, chart: Any, which: int | None = 0, sigma: float | None = None, wide_factor: float | None = WIDE_FACTOR
) -> Residual:
    """:func:`residual_force` on the contiguous segments of a :class:`~lagsplat.chart.Chart`.

    Args:
        model: the fitted model (see :func:`residual_force`).
        chart: the chart (``q``, ``t``, ``u``, ``episode``, ``split``, ``G_bar``).
        which: ``0`` (``TRAIN``, the default: what the diagnosis chooses and fits on),
            ``1`` (``HELD_OUT``) or ``None`` (every frame, segments split by episode only).
        sigma: smoothing, frames (default: automatic).
        wide_factor: smoothing of :attr:`Residual.wide <lagsplat.diagnose.residual_data.Residual.wide>` relative to ``sigma``
            (see :func:`residual_force`).

    Returns:
        The :class:`~lagsplat.diagnose.residual_data.Residual` (``meta["split"]`` records ``which``;
        ``meta["image_error"]`` the chart's per-frame autoencoder error on the same frames,
        :func:`~lagsplat.diagnose.image_signature.image_error_from_chart`, or ``None``).
    """
    from lagsplat.diagnose.image_signature import image_error_from_chart

    segs = chart_segments(chart, which)
    if not segs:
        raise ValueError(f"the chart has no segment with split {which!r}")
    dt = float(np.median(np.diff(chart.t)))
    u = chart.u if chart.u is not None and chart.u.shape[1] else None
    return residual_force(
        model, [chart.q[s] for s in segs], dt, [chart.t[s] for s in segs],
        None if u is None else [u[s] for s in segs], [int(chart.episode[s[0]]) for s in segs],
        chart.G_bar, sigma, {"split": which, "image_error": image_error_from_chart(chart, which)}, wide_factor,
    )  # fmt: skip

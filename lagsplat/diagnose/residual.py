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
de-blurred state and then smoothed by ``G`` (:meth:`Residual.features`), so a
sharp effect (a Coulomb switch, an impact) is compared with its own smoothed
image. De-blurring is the first-order inverse of the heat kernel,
``q ~ G*q - (sigma dt)^2 / 2 G*q''`` (likewise for ``qdot``), which removes the
amplitude loss ``exp(-(w sigma dt)^2 / 2)`` to first order before a nonlinear
feature is evaluated (an end stop's bounce is too sharp for a first-order
inverse: it reads the chart's own positions, :attr:`SegmentState.q_raw`,
whose noise is small beside the penetration). For the model, what de-blurring and re-smoothing leave
of the state is removed through the model's local linearisation, which makes
the comparison exact for a linear model whatever the spectrum of the motion
and of the input (:func:`_smoothed_model_acceleration`). Kernels are truncated at 6 sigma (at 4 sigma the
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
are slower still. So every residual also carries :attr:`Residual.wide`, the
same residual at ``wide_factor`` (1.5) times the smoothing, ``period / 8`` by
default, on which :func:`~lagsplat.diagnose.select_effect` fits those
*out-of-class* candidates: the noise variance (``~ sigma^-5``) falls 7.6x,
the fundamental still passes at 0.73 (0.87 at ``period / 12``), and the
features are evaluated on a state de-blurred from less noisy derivatives.
The in-class candidates (end stop, cubic stiffness) keep the sharp residual.
On the blind suite's pendulum clips at 32 x 32 px the change takes quadratic
drag from Delta BIC 1 / 6 (missed) to 19 / 41 (found) while the controls'
out-of-class candidates stay below zero (``benchmarks/diagnosis.py``).

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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d

from lagsplat import metrics, timeseries

#: Default residual smoothing: ``sigma = period / SIGMA_PER_PERIOD`` frames (clipped to ``[2, 6]``), ``period`` the dominant one in frames.
SIGMA_PER_PERIOD = 12.0
#: The out-of-class candidates' residual is smoothed this many times wider (``period / 8`` by default).
WIDE_FACTOR = 1.5

__all__ = [
    "SIGMA_PER_PERIOD",
    "WIDE_FACTOR",
    "SegmentState",
    "Residual",
    "residual_force",
    "residual_from_chart",
    "chart_noise",
    "LinearOscillator",
    "fit_linear_oscillator",
]


class _Model(Protocol):
    def acceleration(self, q: torch.Tensor, qdot: torch.Tensor, f_ext: torch.Tensor | None = None, u: torch.Tensor | None = None) -> torch.Tensor: ...


@dataclass
class SegmentState:
    """The de-blurred state of one padded segment, the input of candidate features.

    Attributes:
        index: segment number (0-based, in :attr:`Residual.n_segments`).
        episode: recording the segment comes from.
        t: float64 ``[m]`` time in seconds (padded linearly beyond the ends).
        q: float64 ``[m,d]`` de-blurred position.
        qdot: float64 ``[m,d]`` de-blurred velocity, per second.
        u: float64 ``[m,n_u]`` actuation (padded by its end values).
        u_at: ``(t [k]) -> [k,n_u]``: the actuation of the whole segment at any
            time, linearly interpolated (end values outside), for delayed inputs.
        keep: ``slice`` of the padded samples that appear in the residual.
        q_raw: float64 ``[m,d]`` the chart's position itself, unsmoothed (padded by odd
            reflection): what a sharp position-dependent feature reads (an end stop,
            whose bounce the de-blurring cannot restore).
    """

    index: int
    episode: int
    t: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    u: np.ndarray
    u_at: Callable[[np.ndarray], np.ndarray]
    keep: slice
    q_raw: np.ndarray


@dataclass
class Residual:
    """The residual generalized force of a model on a trajectory, with what is needed to explain it.

    All per-sample arrays cover the kept samples of every segment, concatenated
    (``n`` samples in all).

    Attributes:
        dt: frame interval, s.
        sigma: smoothing standard deviation, frames.
        t: float64 ``[n]`` time, s.
        q, qdot, qddot: float64 ``[n,d]`` smoothed position, velocity (per s) and
            acceleration (per s^2) of the chart.
        a_model: float64 ``[n,d]`` the model's acceleration, smoothed like ``qddot``.
        M: float64 ``[n,d,d]`` the model's inertia at ``q`` (identity if it has none).
        r: float64 ``[n,d]`` residual generalized force ``M (qddot - a_model)``.
        f_model: float64 ``[n,d]`` the model's own force ``M a_model`` (for scale).
        u: float64 ``[n,n_u]`` smoothed actuation.
        segment: int ``[n]`` segment of each sample; ``episode``: int ``[n]`` its recording.
        noise_q: float64 ``[d]`` chart noise per sample (latent units).
        noise_r: float64 ``[d]`` standard deviation of that noise's image in ``r``.
        G: float64 ``[d,d]`` metric of the latent space (``G_bar`` of the chart, or identity).
        f_dominant_hz: dominant oscillation frequency of the trajectory.
        spacing: samples per independent residual sample (``max(1, 2 sigma)``), for
            information criteria and standard errors.
        meta: provenance (model kind, split, ...).
        wide: the same residual at the wider smoothing on which the out-of-class
            candidates are fitted (see "Smoothing width" in the module docstring), or
            ``None`` (none asked for, or no segment long enough for it).
    """

    dt: float
    sigma: float
    t: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    qddot: np.ndarray
    a_model: np.ndarray
    M: np.ndarray
    r: np.ndarray
    f_model: np.ndarray
    u: np.ndarray
    segment: np.ndarray
    episode: np.ndarray
    noise_q: np.ndarray
    noise_r: np.ndarray
    G: np.ndarray
    f_dominant_hz: float
    spacing: float
    states: list[SegmentState] = field(default_factory=list, repr=False)
    meta: dict[str, Any] = field(default_factory=dict)
    wide: Residual | None = field(default=None, repr=False)

    @property
    def n(self) -> int:
        """Number of residual samples."""
        return int(len(self.t))

    @property
    def d(self) -> int:
        """Latent dimension."""
        return int(self.q.shape[1])

    @property
    def n_u(self) -> int:
        """Actuation channels."""
        return int(self.u.shape[1])

    @property
    def n_segments(self) -> int:
        """Number of contiguous segments."""
        return len(self.states)

    @property
    def q_raw(self) -> np.ndarray:
        """float64 ``[n,d]`` the chart's unsmoothed position at the residual samples.

        :attr:`q` is smoothed and pulls the turning points in (by about
        ``sigma^2 dt^2 |qddot| / 2``, more at a sharp bounce); an end stop is
        placed, counted and evaluated on this instead (:attr:`SegmentState.q_raw`).
        """
        return np.concatenate([st.q_raw[st.keep] for st in self.states], 0)

    @property
    def n_eff(self) -> float:
        """Effective number of independent samples ``n / spacing``."""
        return self.n / self.spacing

    def smooth(self, x: np.ndarray) -> np.ndarray:
        """``G * x`` along axis 0 of a padded per-segment array (same length)."""
        return gaussian_filter1d(np.asarray(x, np.float64), self.sigma, axis=0, mode="nearest", truncate=6.0)

    def features(self, fn: Callable[[SegmentState], np.ndarray]) -> np.ndarray:
        """Evaluate a candidate's feature on every segment, smooth it like the acceleration, keep the residual samples.

        Args:
            fn: ``SegmentState -> [m, p]`` (or ``[m]``), the generalized-force
                feature(s) at the de-blurred state of the padded segment.

        Returns:
            float64 ``[n, p]``, rows aligned with :attr:`r`.

        Raises:
            ValueError: if ``fn`` returns the wrong number of rows or non-finite values.
        """
        out = []
        for st in self.states:
            phi = np.asarray(fn(st), np.float64)
            if phi.ndim == 1:
                phi = phi[:, None]
            if phi.shape[0] != len(st.t):
                raise ValueError(f"feature returned {phi.shape[0]} rows for a segment of {len(st.t)} samples")
            if not np.all(np.isfinite(phi)):
                raise ValueError("feature returned NaN or inf")
            out.append(self.smooth(phi)[st.keep])
        return np.concatenate(out, 0)

    def project(self, direction: np.ndarray | None = None) -> np.ndarray:
        """Scalar coordinate ``q @ e`` ``[n]`` along ``direction`` (default: the top eigenvector of ``G``)."""
        e = metrics.top_direction(self.G) if direction is None else np.asarray(direction, np.float64)
        return self.q @ e

    def segment_slices(self) -> list[np.ndarray]:
        """Index arrays ``[n_k]`` of each segment's residual samples."""
        return [np.flatnonzero(self.segment == k) for k in range(self.n_segments)]


# ------------------------------------------------------------------ helpers
def chart_noise(segments: Sequence[np.ndarray]) -> np.ndarray:
    """Per-sample white-noise level of a trajectory, from its fourth difference.

    ``Delta^4 q`` cancels a smooth signal (to ``(w dt)^4``) and multiplies white
    noise of std ``s`` by ``sqrt(70)``; the scale is the robust MAD estimate
    ``1.4826 median|x - median x|`` pooled over the segments.

    Args:
        segments: list of ``[m,d]`` raw trajectories (each ``m >= 5``; shorter ones are skipped).

    Returns:
        float64 ``[d]`` noise standard deviation per coordinate.

    Raises:
        ValueError: if no segment has 5 samples.
    """
    d4 = [np.diff(np.asarray(s, np.float64), 4, axis=0) for s in segments if len(s) >= 5]
    if not d4:
        raise ValueError("chart_noise needs a segment of at least 5 samples")
    x = np.concatenate(d4, 0)
    mad = 1.4826 * np.median(np.abs(x - np.median(x, 0)), 0)
    return mad / math.sqrt(70.0)


def _kernel_norm(sigma: float, order: int) -> float:
    """``|g|_2`` of the discrete Gaussian derivative kernel of this order (per frame^order)."""
    n = int(8 * sigma) + 1
    imp = np.zeros(2 * n + 1)
    imp[n] = 1.0
    return float(np.linalg.norm(gaussian_filter1d(imp, sigma, order=order, mode="constant", truncate=6.0)))


def _pad_odd(x: np.ndarray, P: int) -> np.ndarray:
    """Pad ``[m, ...]`` by ``P`` samples at both ends by odd reflection about the end samples."""
    m = len(x)
    P = min(P, m - 1)
    left = 2 * x[0] - x[P:0:-1]
    right = 2 * x[-1] - x[-2 : -P - 2 : -1]
    return np.concatenate([left, x, right], 0), P


def _model_eval(model: Any, q: np.ndarray, qdot: np.ndarray, u: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(a [m,d], M [m,d,d])`` of a model with ``acceleration`` (and optionally ``mass_matrix``)."""
    p = next(iter(model.parameters()), None) if hasattr(model, "parameters") else None
    dtype = p.dtype if p is not None else torch.float64
    Q = torch.as_tensor(q, dtype=dtype)
    V = torch.as_tensor(qdot, dtype=dtype)
    U = None if u is None or u.shape[1] == 0 else torch.as_tensor(u, dtype=dtype)
    was_training = getattr(model, "training", False)
    if hasattr(model, "eval"):
        model.eval()
    try:
        with torch.no_grad():
            a = model.acceleration(Q, V, None, u=U) if U is not None else model.acceleration(Q, V)
            M = model.mass_matrix(Q) if hasattr(model, "mass_matrix") else torch.eye(q.shape[1], dtype=dtype).expand(len(q), -1, -1)
    finally:
        if was_training:
            model.train()
    return a.detach().double().numpy(), M.detach().double().numpy()


def _smoothed_model_acceleration(
    model: Any, q_t: np.ndarray, qd_t: np.ndarray, u_raw: np.ndarray | None, q_s: np.ndarray, qd_s: np.ndarray,
    u_s: np.ndarray | None, keep: slice, sigma: float,
) -> np.ndarray:
    """``G * a(q, qdot, u)`` of the true state, estimated on the kept samples ``[m,d]``.

    ``G * a(q~, qdot~, u)`` at the de-blurred state, minus the model's local
    linearisation applied to what de-blurring and re-smoothing leave of the
    state, ``J_q (G*q~ - G*q) + J_qdot (G*qdot~ - G*qdot)``: exact for a linear
    model (whatever the spectrum of the motion and the input), and a smooth
    nonlinear model's own curvature is still averaged over the kernel as the
    data are. ``J`` by central differences at the smoothed state.
    """
    a_raw, _ = _model_eval(model, q_t, qd_t, u_raw)
    sm = lambda x: gaussian_filter1d(x, sigma, axis=0, mode="nearest", truncate=6.0)
    a = sm(a_raw)[keep]
    dq, dv = (sm(q_t) - q_s)[keep], (sm(qd_t) - qd_s)[keep]
    q0, v0 = q_s[keep], qd_s[keep]
    u0 = None if u_s is None else u_s[keep]
    d = q0.shape[1]
    for j in range(d):
        for base, delta, scale in ((q0, dq, np.std(q0[:, j]) + 1e-12), (v0, dv, np.std(v0[:, j]) + 1e-12)):
            h = 1e-3 * scale
            plus, minus = base.copy(), base.copy()
            plus[:, j] += h
            minus[:, j] -= h
            if base is q0:
                ap, _ = _model_eval(model, plus, v0, u0)
                am, _ = _model_eval(model, minus, v0, u0)
            else:
                ap, _ = _model_eval(model, q0, plus, u0)
                am, _ = _model_eval(model, q0, minus, u0)
            a = a - (ap - am) / (2 * h) * delta[:, j : j + 1]
    return a


def _dominant_frequency(segs: Sequence[np.ndarray], dt: float, G: np.ndarray) -> float:
    longest = max(segs, key=len)
    e = metrics.top_direction(G)
    try:
        return float(timeseries.spectral_peak_frequency(longest @ e, dt))
    except ValueError:
        return float("nan")


# ------------------------------------------------------------------ main entry
def residual_force(
    model: _Model,
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
    """The residual generalized force ``r = M (qddot - a_model)`` of a model on contiguous trajectories.

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
        wide_factor: also compute :attr:`Residual.wide` at ``wide_factor * sigma``
            (``None`` or ``<= 1``: no wide residual); see "Smoothing width" in the module docstring.

    Returns:
        The :class:`Residual`.

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
    episodes = list(range(len(segs))) if episodes is None else [int(e) for e in episodes]
    f_dom = _dominant_frequency(segs, dt, G)
    if sigma is None:
        period = 1.0 / (f_dom * dt) if math.isfinite(f_dom) and f_dom > 0 else 24.0
        sigma = float(np.clip(period / SIGMA_PER_PERIOD, 2.0, 6.0))
    sigma = float(sigma)
    if not (sigma > 0):
        raise ValueError(f"sigma must be positive, got {sigma!r}")
    P = int(math.ceil(6 * sigma))
    trim = int(math.ceil(3 * sigma))
    min_len = 2 * trim + 8
    noise_q = chart_noise(segs)
    blur = 0.5 * (sigma * dt) ** 2

    cols: dict[str, list] = {k: [] for k in ("t", "q", "qd", "qdd", "a", "M", "u", "seg", "ep")}
    states: list[SegmentState] = []
    for q_raw, t_raw, u_raw, ep in zip(segs, t_segments, u_segments, episodes):
        t_raw = np.asarray(t_raw, np.float64)
        u_raw = np.asarray(u_raw, np.float64).reshape(len(q_raw), n_u)
        if len(q_raw) < min_len:
            continue
        if len(t_raw) != len(q_raw):
            raise ValueError(f"a segment has {len(q_raw)} positions but {len(t_raw)} times")
        qp, Pk = _pad_odd(q_raw, P)
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
        a_s = _smoothed_model_acceleration(model, q_t, qd_t, up if n_u else None, q_s, qd_s, u_s if n_u else None, keep, sigma)
        _, M = _model_eval(model, q_s[keep], qd_s[keep], u_s[keep] if n_u else None)

        def u_at(tq: np.ndarray, _t: np.ndarray = t_raw, _u: np.ndarray = u_raw) -> np.ndarray:
            tq = np.asarray(tq, np.float64)
            return np.stack([np.interp(tq, _t, _u[:, j]) for j in range(_u.shape[1])], -1) if _u.shape[1] else np.zeros((len(tq), 0))

        states.append(SegmentState(len(states), ep, tp, q_t, qd_t, up, u_at, keep, qp))
        cols["t"].append(tp[keep])
        cols["q"].append(q_s[keep])
        cols["qd"].append(qd_s[keep])
        cols["qdd"].append(qdd_s[keep])
        cols["a"].append(a_s)
        cols["M"].append(M)
        cols["u"].append(u_s[keep])
        cols["seg"].append(np.full(len(M), len(states) - 1))
        cols["ep"].append(np.full(len(M), ep))
    if not states:
        raise ValueError(f"no segment is long enough for the residual: need more than {min_len} samples at sigma = {sigma:.1f} frames")
    cat = {k: np.concatenate(v, 0) for k, v in cols.items()}
    M = cat["M"]
    r = np.einsum("nij,nj->ni", M, cat["qdd"] - cat["a"])
    f_model = np.einsum("nij,nj->ni", M, cat["a"])
    s_qdd = noise_q * _kernel_norm(sigma, 2) / dt**2
    M_bar = M.mean(0)
    noise_r = np.sqrt((M_bar**2) @ (s_qdd**2))
    out = Residual(
        dt=float(dt), sigma=sigma, t=cat["t"], q=cat["q"], qdot=cat["qd"], qddot=cat["qdd"], a_model=cat["a"], M=M,
        r=r, f_model=f_model, u=cat["u"], segment=cat["seg"].astype(int), episode=cat["ep"].astype(int),
        noise_q=noise_q, noise_r=np.maximum(noise_r, 1e-12), G=G, f_dominant_hz=f_dom, spacing=max(1.0, 2.0 * sigma),
        states=states, meta=dict(meta or {}),
    )  # fmt: skip
    if wide_factor is not None and wide_factor > 1.0:
        try:
            out.wide = residual_force(*args, sigma=sigma * float(wide_factor), meta=meta, wide_factor=None)
        except ValueError:  # no segment long enough for the wider kernel: the out-of-class candidates use this one
            out.wide = None
    return out


def residual_from_chart(
    model: _Model, chart: Any, which: int | None = 0, sigma: float | None = None, wide_factor: float | None = WIDE_FACTOR
) -> Residual:
    """:func:`residual_force` on the contiguous segments of a :class:`~lagsplat.chart.Chart`.

    Args:
        model: the fitted model (see :func:`residual_force`).
        chart: the chart (``q``, ``t``, ``u``, ``episode``, ``split``, ``G_bar``).
        which: ``0`` (``TRAIN``, the default: what the diagnosis chooses and fits on),
            ``1`` (``HELD_OUT``) or ``None`` (every frame, segments split by episode only).
        sigma: smoothing, frames (default: automatic).
        wide_factor: smoothing of :attr:`Residual.wide` relative to ``sigma`` (see :func:`residual_force`).

    Returns:
        The :class:`Residual` (``meta["split"]`` records ``which``).
    """
    from lagsplat.io.clip import segments as split_segments

    if which is None:
        segs = split_segments(np.zeros(len(chart.t), np.int8), 0, chart.episode)
    else:
        segs = chart.segments(int(which))
    if not segs:
        raise ValueError(f"the chart has no segment with split {which!r}")
    dt = float(np.median(np.diff(chart.t)))
    u = chart.u if chart.u is not None and chart.u.shape[1] else None
    return residual_force(
        model, [chart.q[s] for s in segs], dt, [chart.t[s] for s in segs],
        None if u is None else [u[s] for s in segs], [int(chart.episode[s[0]]) for s in segs],
        chart.G_bar, sigma, {"split": which}, wide_factor,
    )  # fmt: skip


# ------------------------------------------------------------------ linear stand-in
class LinearOscillator(torch.nn.Module):
    """A linear model with the Lagrangian's interface: ``qddot = -K (q - q0) - C qdot + B u`` (unit inertia).

    The stand-in "plain damped oscillator" of the latent-level tests and
    benchmark (no Stage 1, no Stage 2 training): fitted in closed form by
    :func:`fit_linear_oscillator`.

    Args:
        K, C: ``[d,d]`` stiffness and damping (per s^2, per s).
        q0: ``[d]`` rest position.
        B: ``[d,n_u]`` input gain (``None``: no actuation).
    """

    def __init__(self, K: np.ndarray, C: np.ndarray, q0: np.ndarray, B: np.ndarray | None = None) -> None:
        super().__init__()
        d = len(q0)
        self.d = d
        self.register_buffer("K", torch.as_tensor(np.asarray(K, np.float64).reshape(d, d)))
        self.register_buffer("C", torch.as_tensor(np.asarray(C, np.float64).reshape(d, d)))
        self.register_buffer("q0", torch.as_tensor(np.asarray(q0, np.float64).reshape(d)))
        B = np.zeros((d, 0)) if B is None else np.asarray(B, np.float64).reshape(d, -1)
        self.register_buffer("B", torch.as_tensor(B))
        self.n_u = int(B.shape[1])

    def acceleration(self, q: torch.Tensor, qdot: torch.Tensor, f_ext: torch.Tensor | None = None, u: torch.Tensor | None = None) -> torch.Tensor:
        """``qddot [B,d]``; ``f_ext [B,d]`` adds directly (unit inertia); ``u [B,n_u]``."""
        K, C = self.K.to(q.dtype), self.C.to(q.dtype)
        a = -(q - self.q0.to(q.dtype)) @ K.T - qdot @ C.T
        if f_ext is not None:
            a = a + f_ext
        if u is not None and self.n_u:
            a = a + u.to(q.dtype) @ self.B.to(q.dtype).T
        return a

    def mass_matrix(self, q: torch.Tensor) -> torch.Tensor:
        """Identity inertia ``[B,d,d]``."""
        return torch.eye(self.d, dtype=q.dtype).expand(q.shape[0], self.d, self.d)

    def modal_analysis(self) -> dict[str, np.ndarray]:
        """``{"f_hz", "zeta"}`` of the linear modes (sorted by frequency)."""
        d = self.d
        A = np.zeros((2 * d, 2 * d))
        A[:d, d:] = np.eye(d)
        A[d:, :d] = -self.K.numpy()
        A[d:, d:] = -self.C.numpy()
        lam = np.linalg.eigvals(A)
        lam = lam[lam.imag > 1e-12]
        order = np.argsort(np.abs(lam))
        lam = lam[order]
        return {"f_hz": np.abs(lam) / (2 * math.pi), "zeta": -lam.real / np.abs(lam)}


def fit_linear_oscillator(
    q_segments: Sequence[np.ndarray], dt: float, u_segments: Sequence[np.ndarray] | None = None, sigma: float = 2.0
) -> LinearOscillator:
    """Least-squares linear oscillator on smoothed trajectories (the "plain model" stand-in).

    Regresses ``qddot`` on ``[q, qdot, 1, u]`` (Gaussian derivative filters of
    ``sigma`` frames, ``2 ceil(3 sigma)`` edge samples dropped per segment).

    Args:
        q_segments: list of ``[m,d]`` trajectories.
        dt: frame interval, s.
        u_segments: list of ``[m,n_u]`` actuation, or ``None``.
        sigma: smoothing, frames.

    Returns:
        The fitted :class:`LinearOscillator`.

    Raises:
        ValueError: if there are fewer samples than unknowns.
    """
    rows, ys = [], []
    trim = int(math.ceil(3 * sigma))
    for k, q in enumerate(q_segments):
        q = np.asarray(q, np.float64)
        if len(q) <= 2 * trim + 2:
            continue
        f = [gaussian_filter1d(q, sigma, axis=0, order=o, mode="nearest") / dt**o for o in range(3)]
        u = np.zeros((len(q), 0)) if u_segments is None else np.asarray(u_segments[k], np.float64).reshape(len(q), -1)
        X = np.concatenate([f[0], f[1], np.ones((len(q), 1)), gaussian_filter1d(u, sigma, axis=0, mode="nearest") if u.shape[1] else u], 1)
        rows.append(X[trim:-trim])
        ys.append(f[2][trim:-trim])
    if not rows:
        raise ValueError("fit_linear_oscillator: no segment is long enough")
    X, Y = np.concatenate(rows), np.concatenate(ys)
    if len(X) <= X.shape[1]:
        raise ValueError(f"fit_linear_oscillator: {len(X)} samples for {X.shape[1]} unknowns")
    W, *_ = np.linalg.lstsq(X, Y, rcond=None)
    d = Y.shape[1]
    K, C, b = -W[:d].T, -W[d : 2 * d].T, W[2 * d]
    B = W[2 * d + 1 :].T if X.shape[1] > 2 * d + 1 else None
    q0 = np.linalg.lstsq(K, b, rcond=None)[0]
    return LinearOscillator(K, C, q0, B)

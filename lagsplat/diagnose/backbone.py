"""Backbone curves: the oscillation's frequency and damping ratio against its amplitude, read off the video and off models.

The standard picture of nonlinear vibration analysis. A hardening spring's frequency rises with the amplitude
(a Duffing spring ``qddot + w0^2 q + beta q^3 = 0``: ``w(A) ~ w0 (1 + 3 beta A^2 / (8 w0^2))``), a pendulum's
falls; viscous damping keeps the damping ratio ``zeta`` flat, dry friction raises it as the amplitude falls
(``zeta ~ 2 mu / (pi w0^2 A)``) and quadratic drag the reverse.

Every reading comes from one estimator, :func:`local_backbone`, on a scalar coordinate ``p = q @ e`` along the
chart's most visible direction ``e`` (top eigenvector of ``G_bar``, as the evaluation and the signatures of
:mod:`lagsplat.diagnose.signatures` project): the turning points of
:func:`~lagsplat.diagnose.signatures.turning_points` (timed to a fraction of a frame), then per pair of successive
opposite turning points the amplitude ``H = |p_k - p_k+1| / 2`` (half the peak-to-peak swing: no centre to
estimate) and the frequency ``1 / (2 (t_k+1 - t_k))``, and per cycle the logarithmic decrement
``delta = log(H_k / H_k+2)`` and ``zeta = delta / sqrt(4 pi^2 + delta^2)`` (exact for a linear viscous decay; over a
whole cycle, so that a model whose damping differs on the two sides of its swing does not alternate). :func:`backbone` reads the encoded video (every frame: the backbone decides nothing, the held-out ones
are marked; smoothed against the chart noise, each swing's amplitude divided by the smoothing's gain at its
frequency) and the free rollouts of each model (the identified Stage-2 model, paper Eq. 7, and the diagnosis's
refit) released at rest at amplitudes spanning the recorded ones (noise-free, read unsmoothed).

Units: time in s, frequency in Hz, amplitude in chart units (whitened ``q``), ``zeta`` dimensionless.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch

from lagsplat import metrics
from lagsplat.diagnose.signatures import MIN_AMPLITUDE_OVER_NOISE, turning_gap, turning_points
from lagsplat.dynamics.integrators import rollout
from lagsplat.io.clip import HELD_OUT, segments

__all__ = ["MIN_READINGS", "N_RELEASES", "local_backbone", "model_backbone", "trend", "backbone"]

#: fewest frequency readings of the video for a backbone to be drawn
MIN_READINGS = 4

#: free releases of each model, spread evenly over the recorded amplitudes
N_RELEASES = 6

_KEYS = ("amplitude", "frequency_hz", "zeta_amplitude", "zeta")


def local_backbone(
    p: np.ndarray, t: np.ndarray, runs: Sequence[np.ndarray], f_hz: float, min_amplitude: float = 0.0, sigma: float = 0.0,
) -> dict[str, np.ndarray]:
    """The local frequency and damping ratio of a scalar oscillation at each of its swings.

    Args:
        p: ``[n]`` the coordinate, any units (smoothed over ``sigma`` frames, or not).
        t: ``[n]`` times, s.
        runs: index arrays of the contiguous runs to read (a reading never spans two).
        f_hz: the oscillation's dominant frequency, Hz (turning points of one kind at least 0.35 periods apart).
        min_amplitude: swings below this amplitude are not read (units of ``p``).
        sigma: the Gaussian smoothing ``p`` went through, frames. It scales a sinusoid of frequency ``f`` by
            ``g = exp(-(2 pi f sigma dt)^2 / 2)`` and shifts every turning point alike: each swing's amplitude is
            divided by ``g`` at the swing's own frequency (times and ratios need nothing), and turning points
            closer than ``3 sigma`` samples (at least 2) to a run's ends, where the smoothing's edge bends them,
            are not read.

    Returns:
        ``amplitude [k]``, ``frequency_hz [k]`` and ``index [k]`` (the frame of the swing's first turning
        point) per swing between two successive opposite turning points; per cycle (three successive swings)
        ``zeta [m]`` from the first and the third, ``zeta_amplitude [m]`` and ``zeta_index [m]`` the middle
        one's. Float64 arrays, in time order within each run.
    """
    p, t = np.asarray(p, np.float64), np.asarray(t, np.float64)
    out: dict[str, list[float]] = {k: [] for k in (*_KEYS, "index", "zeta_index")}
    for idx in runs:
        if len(idx) < 5:
            continue
        dt = float(np.median(np.diff(t[idx])))
        i, te, v, kind = turning_points(p[idx], t[idx], turning_gap(f_hz, dt), refine=True)
        edge = max(2, int(math.ceil(3 * sigma)))
        inside = (i >= edge) & (i <= len(idx) - 1 - edge)
        i, te, v, kind = i[inside], te[inside], v[inside], kind[inside]
        chain: list[tuple[float, float]] = []  # (amplitude, frame) of the unbroken run of swings so far
        for k in range(len(te) - 1):
            half = te[k + 1] - te[k]
            gain = math.exp(-0.5 * (math.pi * sigma * dt / half) ** 2) if half > 0 else 1.0  # 2 pi f sigma dt, f = 1 / (2 half)
            h = 0.5 * abs(v[k + 1] - v[k]) / gain
            ok = kind[k] != kind[k + 1] and half > 0 and h >= min_amplitude and (v[k] - v[k + 1]) * kind[k] > 0
            if not ok:
                chain = []
                continue
            out["amplitude"].append(h)
            out["frequency_hz"].append(0.5 / half)
            out["index"].append(float(idx[i[k]]))
            chain.append((h, float(idx[i[k]])))
            if len(chain) >= 3:  # one cycle: the swing two before over this one, the middle swing's amplitude
                delta = math.log(chain[-3][0] / h)
                out["zeta_amplitude"].append(chain[-2][0])
                out["zeta"].append(delta / math.sqrt(4 * math.pi**2 + delta**2))
                out["zeta_index"].append(chain[-2][1])
    return {k: np.asarray(v, np.float64) for k, v in out.items()}


def _rest_state(model: Any, d: int) -> np.ndarray:
    """The model's rest state ``[d]``: a Lagrangian's ``q_rest`` (a refit model's base's), a linear oscillator's ``q0``."""
    for m in (model, getattr(model, "base", None)):
        for name in ("q_rest", "q0"):
            r = getattr(m, name, None) if m is not None else None
            if isinstance(r, torch.Tensor) and r.numel() == d:
                return r.detach().double().numpy().reshape(d)
    return np.zeros(d)


@torch.no_grad()
def model_backbone(
    model: Any, direction: np.ndarray, amplitudes: np.ndarray, dt: float, n_steps: int, f_hz: float, min_amplitude: float = 0.0,
    t0: float = 0.0, time_channel: bool = False,
) -> dict[str, np.ndarray]:
    """:func:`local_backbone` of a model's free rollouts released at rest at each amplitude along ``direction``.

    Each rollout starts at ``q_rest + A e``, ``qdot = 0`` (velocity Verlet at the frame step, the compiled path of
    :mod:`lagsplat.dynamics.fast` where the model supports it) and is read like the video, projected on ``e`` (without
    smoothing: a rollout carries no noise); its first swing starts at the release.

    Args:
        model: an ``acceleration`` model (:class:`~lagsplat.models.lagrangian.Lagrangian`, a refit model, ...).
        direction: ``[d]`` unit direction ``e``.
        amplitudes: ``[B]`` release amplitudes, chart units.
        dt: step, s (the chart's frame interval).
        n_steps: states per rollout.
        f_hz: the oscillation's frequency, Hz (:func:`local_backbone`).
        min_amplitude: swings below it are not read.
        t0: clock at the release, s; with ``time_channel`` the model reads it as its last input.
        time_channel: the model reads the clock as an input (a refit with a drift).

    Returns:
        :func:`local_backbone`'s arrays over all releases, with ``release [k]`` and ``zeta_release [m]``
        (which release each reading comes from). A rollout that becomes non-finite is read up to there.
    """
    e = np.asarray(direction, np.float64)
    A = np.asarray(amplitudes, np.float64)
    p0 = next(iter(model.parameters()), None) if hasattr(model, "parameters") else None
    dtype = p0.dtype if p0 is not None else torch.float64
    q0 = torch.as_tensor(_rest_state(model, len(e))[None] + A[:, None] * e[None], dtype=dtype)
    u = (lambda s: torch.full((len(A), 1), float(s), dtype=dtype)) if time_channel else None
    was_training = bool(getattr(model, "training", False))
    if hasattr(model, "eval"):
        model.eval()  # the compiled path wants eval mode
    try:
        q, _ = rollout(model, q0, torch.zeros_like(q0), dt, int(n_steps), t0=t0, u=u)
    finally:
        if was_training:
            model.train()
    out: dict[str, list[np.ndarray]] = {}
    for j, qj in enumerate(q.double().numpy()):
        p = qj @ e
        bad = np.flatnonzero(~np.isfinite(p))
        n = int(bad[0]) if len(bad) else len(p)
        # the release is a turning point at the rollout's first state: mirrored in time about it (the refinement's
        # parabola then sees the two sides of it), it is read like any other
        p = np.concatenate([p[1:n][::-1], p[:n]])
        ts = t0 + dt * np.arange(-(n - 1), n) if n else np.zeros(0)
        r = local_backbone(p, ts, [np.arange(len(p))], f_hz, min_amplitude)
        # the swings from the release on; a cycle's first swing (the one before its middle) too
        keep, keep_z = r.pop("index") >= n - 1, r.pop("zeta_index") > n - 1
        r = {k: v[keep_z if k.startswith("zeta") else keep] for k, v in r.items()}
        r["release"], r["zeta_release"] = np.full(len(r["amplitude"]), j), np.full(len(r["zeta"]), j)
        for k, v in r.items():
            out.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in out.items()}


def trend(r: Mapping[str, np.ndarray], a_lo: float, a_hi: float) -> dict[str, float]:
    """The readings' trend between two amplitudes: ``f = f0 + c A^2`` (the Duffing form) and ``zeta = z0 + z1 A``.

    Fitted on the readings within ``[0.9 a_lo, 1.1 a_hi]``. Returns the frequency at both ends (Hz), its relative
    change ``f(a_hi) / f(a_lo) - 1`` with the standard error, and ``zeta`` at both ends with the standard error of
    their difference; ``nan`` where fewer than 3 readings fall in the range.
    """
    out = {k: math.nan for k in ("f_lo_hz", "f_hi_hz", "f_change", "f_change_se", "zeta_lo", "zeta_hi", "zeta_change_se")}
    for a_key, y_key, basis, keys in (
        ("amplitude", "frequency_hz", lambda a: a * a, ("f_lo_hz", "f_hi_hz")), ("zeta_amplitude", "zeta", lambda a: a, ("zeta_lo", "zeta_hi")),
    ):  # fmt: skip
        a, y = np.asarray(r.get(a_key, []), np.float64), np.asarray(r.get(y_key, []), np.float64)
        m = (a >= 0.9 * a_lo) & (a <= 1.1 * a_hi) & np.isfinite(y)
        if m.sum() < 3 or np.ptp(basis(a[m])) <= 0:
            continue
        X = np.stack([np.ones(int(m.sum())), basis(a[m])], 1)
        c, *_ = np.linalg.lstsq(X, y[m], rcond=None)
        dof = max(int(m.sum()) - 2, 1)
        s2 = float(np.sum((y[m] - X @ c) ** 2)) / dof
        se = math.sqrt(max(s2 * float(np.linalg.pinv(X.T @ X)[1, 1]), 0.0))
        lo, hi, span = c[0] + c[1] * basis(a_lo), c[0] + c[1] * basis(a_hi), basis(a_hi) - basis(a_lo)
        out[keys[0]], out[keys[1]] = float(lo), float(hi)
        if y_key == "frequency_hz":
            out["f_change"], out["f_change_se"] = float(hi / lo - 1.0), float(se * span / lo)
        else:
            out["zeta_change_se"] = float(se * span)
    return out


def _reading(video: Mapping[str, float], models: Mapping[str, Mapping[str, float]], a_lo: float, a_hi: float) -> str:
    """One sentence: how frequency and damping ratio change from the smallest to the largest recorded amplitude."""

    def pct(x: float) -> str:
        return "n/a" if not math.isfinite(x) else f"{100 * x:+.1f} %"

    def z(x: float, fmt: str = ".2g") -> str:
        return "n/a" if not math.isfinite(x) else format(x, fmt)

    fc = video["f_change"]
    s = f"from amplitude {a_lo:.3g} to {a_hi:.3g} (chart units) the recorded frequency "
    s += (f"{'rises' if fc > 0 else 'falls'} {100 * abs(fc):.1f} % (± {100 * video['f_change_se']:.1g})" if math.isfinite(fc)
          else "changes by an amount too few swings can tell")  # fmt: skip
    s += "".join(f"; the {k}'s {pct(v['f_change'])}" for k, v in models.items())
    s += (f"; the damping ratio goes from {z(video['zeta_lo'])} to {z(video['zeta_hi'])} (± {z(video['zeta_change_se'], '.1g')})"
          + "".join(f", the {k}'s from {z(v['zeta_lo'])} to {z(v['zeta_hi'])}" for k, v in models.items()))  # fmt: skip
    return s[:1].upper() + s[1:] + "."


def _lists(r: Mapping[str, np.ndarray]) -> dict[str, list[float]]:
    return {k: [float(x) for x in v] for k, v in r.items()}


def backbone(chart: Any, res: Any, models: Mapping[str, tuple[Any, bool]], n_releases: int = N_RELEASES) -> dict[str, Any]:
    """The backbone record of a recording and its models (``report.json``'s ``backbone``).

    The video's readings come from every frame of the chart (each contiguous run of one episode, smoothed over the
    residual's ``sigma`` frames, :func:`local_backbone`, and projected on the top eigenvector of ``G_bar``), swings below
    :data:`~lagsplat.diagnose.signatures.MIN_AMPLITUDE_OVER_NOISE` chart-noise levels left out. Each model is
    released at ``n_releases`` amplitudes from the smallest to 1.05 times the largest recorded one and rolled out
    for the longest run's length; its readings below 0.9 times the smallest recorded amplitude are left out.

    Args:
        chart: the :class:`~lagsplat.chart.Chart`.
        res: the diagnosis's :class:`~lagsplat.diagnose.residual_data.Residual` (``sigma``, ``noise_q``,
            ``f_dominant_hz``).
        models: ``{label: (model, time_channel)}``, e.g. ``{"identified model": (model, False)}``.
        n_releases: releases per model.

    Returns:
        ``{"done": False, "reason"}`` when it cannot be read (a driven recording, too few swings), else ``done``,
        ``direction``, ``video`` (the readings as lists, with ``held_out [k]``), ``models`` (``{label: readings
        with release_amplitudes}``, or ``{"error"}``), ``trend`` (:func:`trend` of each, video first) and ``reading``.
    """
    if int(getattr(chart, "n_u", 0) or 0) > 0:
        return {"done": False, "reason": "the recording is driven (it has inputs): its swings are not a free oscillation's"}
    f_hz = float(res.f_dominant_hz)
    if not (math.isfinite(f_hz) and f_hz > 0):
        return {"done": False, "reason": "no dominant frequency to find turning points at"}
    e = metrics.top_direction(chart.G_bar)
    noise = float(np.max(res.noise_q))
    runs = segments(np.zeros(len(chart.t), np.int8), 0, chart.episode)
    p = np.zeros(len(chart.t))
    for idx in runs:
        p[idx] = res.smooth(np.asarray(chart.q[idx], np.float64)) @ e
    video = local_backbone(p, np.asarray(chart.t, np.float64), runs, f_hz, MIN_AMPLITUDE_OVER_NOISE * noise, res.sigma)
    n = len(video["amplitude"])
    if n < MIN_READINGS:
        return {"done": False, "reason": f"{n} swing(s) above {MIN_AMPLITUDE_OVER_NOISE:g} chart-noise levels (a backbone needs {MIN_READINGS})"}
    a_lo, a_hi = float(video["amplitude"].min()), float(video["amplitude"].max())
    released = np.linspace(a_lo, 1.05 * a_hi, n_releases)
    dt = float(np.median(np.diff(chart.t[runs[0]]))) if len(runs[0]) > 1 else float(res.dt)
    n_steps = max(len(r) for r in runs)
    out_models: dict[str, Any] = {}
    trends = {"video": trend(video, a_lo, a_hi)}
    for label, (model, time_channel) in models.items():
        try:
            r = model_backbone(model, e, released, dt, n_steps, f_hz, 0.9 * a_lo, float(chart.t[0]), time_channel)
        except (RuntimeError, ValueError) as exc:  # a model that cannot be rolled out here: said, not fatal
            out_models[label] = {"error": str(exc)}
            continue
        out_models[label] = {"release_amplitudes": [float(a) for a in released], **_lists(r)}
        trends[label] = trend(r, a_lo, a_hi)
    split = np.asarray(chart.split)
    held, zeta_held = (split[video.pop(k).astype(int)] == HELD_OUT for k in ("index", "zeta_index"))
    model_trends = {k: v for k, v in trends.items() if k != "video"}
    return {
        "done": True, "reason": None, "direction": [float(v) for v in e], "amplitude_range": [a_lo, a_hi], "f_dominant_hz": f_hz,
        "units": {"amplitude": "chart units along the top G_bar direction (half the peak-to-peak swing)", "frequency_hz": "Hz", "zeta": "1"},
        "video": {**_lists(video), "held_out": [bool(h) for h in held], "zeta_held_out": [bool(h) for h in zeta_held]}, "models": out_models, "trend": trends,
        "reading": _reading(trends["video"], model_trends, a_lo, a_hi),
    }  # fmt: skip

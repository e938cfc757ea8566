"""The decay law of the whole training trajectory: dry friction, quadratic drag or viscous damping.

The envelope signature (:func:`lagsplat.diagnose.signatures.signatures`) reads the decay from the
turning points alone, a dozen numbers on a clip of a few periods. The same question asked of every
sample is far sharper: fit the chart's own positions along the effect's direction, segment by
segment, with a free oscillator whose state is integrated over the whole segment (single shooting),

``s'' = -k s - k2 s^2 - k3 s^3 - k4 s^4 - c s' - (kappa + kappa1 s) s'^2 [- mu tanh(s' / v_s) | - c2 |s'| s']``,

with the initial state, an offset and the oscillator's base (all but the added law's term) per segment:
recordings released at different amplitudes see different stretches of an anharmonic potential and of the
chart's distortion, which a base shared across them fits only on average, leaving a misfit that grows
with the amplitude as a dry-friction term does (on the blind suite's pendulum controls a shared base reads
dry friction far more strongly than a base per take; ``docs/experiments/diagnosis_history.md``). The law's
coefficient, one physical constant, is shared. The in-class terms are free in every fit:
``k2..k4`` an anharmonic, asymmetric potential, and ``kappa + kappa1 s`` the Christoffel term of a
position-dependent mass, which is what a smooth distortion of the chart adds (with ``x = h(s)``, a
viscous oscillator in ``x`` reads ``s'' = -(h''/h') s'^2 - V'(h) / (m h') - (c/m) s'`` in ``s``: its
damping is unchanged). So the only thing the added term can buy is a decay that is not exponential: dry friction (paper §3.3: the amplitude falls by a constant step per
cycle, so the motion loses its amplitude faster, relative to it, as it shrinks) or quadratic drag
(faster at large amplitude). A term that takes the wrong sign buys the opposite law and is no
evidence for the effect.

Evidence is on the ``Delta BIC`` scale of the regressions, with the sample count reduced for the
serial correlation of the oscillator's misfit: ``n_eff log(SSR_viscous / SSR_law) - log n_eff``,
``n_eff = n (1 - rho) / (1 + rho)`` (``rho`` the lag-one autocorrelation of the viscous fit's
residual; Bartlett's effective sample size of an AR(1) series). Read on unactuated charts with
``d = 1`` only (an input or a second mode makes the free oscillator the wrong null).

A law counts only at a practical size (:data:`MIN_LOSS_PER_PERIOD`): on thousands of samples a
fraction of a percent of bend in an exponential decay reaches the evidence threshold, and that is
not the dry friction or drag a physicist would report.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit

__all__ = ["decay_law", "law_evidence", "LAWS", "LAW_NAMES", "MIN_LOSS_PER_PERIOD"]

#: The non-viscous decay laws tested; each coefficient must be positive to count.
LAWS = ("dry", "drag")
#: What the report calls each law.
LAW_NAMES = {"dry": "dry friction", "drag": "quadratic drag"}

_BASE = 7  # k, c, k2, k3, kappa, k4, kappa1
_PER_SEGMENT = _BASE + 3  # the base, then the initial position, velocity and the offset
#: Shortest segment read, periods: four half-cycles, three decrements to tell a constant from a proportional loss.
#: A clip cut to three periods of training frames keeps a segment a little shorter than three; on the realistic
#: suite so cut, no control reads a sign-correct law and drag is still read (docs/experiments/diagnosis_history.md).
_MIN_PERIODS = 2.0
_KIND = {"viscous": 0, "dry": 1, "drag": 2}
#: Practical size of a law: the amplitude it alone removes per period, relative to the largest amplitude. Dry friction
#: ``mu`` (acceleration) takes ``4 mu / w^2`` per period; quadratic drag ``c2`` takes ``8/3 c2 A^2`` of ``A`` (its work
#: per cycle, ``8/3 c2 w^2 A^3``, over the energy ``w^2 A^2 / 2``, halved). The threshold lies between what the suites'
#: dry-friction and drag clips lose per period to their law and the fraction of a percent by which a control's
#: exponential decay is bent where it passes the evidence threshold: an exponential decay bent that little is not a law
#: to report (measured on the cached suites: docs/experiments/diagnosis_history.md,
#: docs/experiments/code_comment_history.md).
MIN_LOSS_PER_PERIOD = 0.01


@njit(cache=True)
def _accel(kind: int, s: float, v: float, p: np.ndarray, v_s: float) -> float:
    a = -p[0] * s - p[2] * s * s - p[3] * s**3 - p[5] * s**4 - p[1] * v - (p[4] + p[6] * s) * v * v
    if kind == 1:
        a -= p[7] * math.tanh(v / v_s)
    elif kind == 2:
        a -= p[7] * abs(v) * v
    return a


@njit(cache=True)
def _rk4(kind: int, t: np.ndarray, p: np.ndarray, s: float, v: float, v_s: float, substeps: int) -> np.ndarray:
    ys = np.empty(len(t))
    ys[0] = s
    for i in range(1, len(t)):
        h = (t[i] - t[i - 1]) / substeps
        for _ in range(substeps):
            a1 = _accel(kind, s, v, p, v_s)
            s2, v2 = s + 0.5 * h * v, v + 0.5 * h * a1
            a2 = _accel(kind, s2, v2, p, v_s)
            s3, v3 = s + 0.5 * h * v2, v + 0.5 * h * a2
            a3 = _accel(kind, s3, v3, p, v_s)
            s4, v4 = s + h * v3, v + h * a3
            a4 = _accel(kind, s4, v4, p, v_s)
            s, v = s + h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4), v + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        ys[i] = s
    return ys


def _layout(kind: str, n_segments: int) -> tuple[int, list[slice]]:
    """Where the parameters sit in ``P = [law coefficient (not for "viscous"), (base..., s0, v0, offset) per segment]``:
    ``(number of law coefficients, each segment's slice)``."""
    n_law = int(kind != "viscous")
    return n_law, [slice(n_law + _PER_SEGMENT * j, n_law + _PER_SEGMENT * (j + 1)) for j in range(n_segments)]


def _simulate(kind: str, P: np.ndarray, segs: list[tuple[np.ndarray, np.ndarray]], v_s: float, substeps: int) -> np.ndarray:
    """Positions of every segment under ``P`` (:func:`_layout`), RK4 on the frame grid: the oscillator's base
    (:data:`_BASE` terms) is each segment's own, the law's coefficient shared."""
    n_law, blocks = _layout(kind, len(segs))
    phys = np.zeros(_BASE + 1)
    phys[_BASE] = P[0] if n_law else 0.0
    out = []
    for (t, _), sl in zip(segs, blocks):
        blk = P[sl]
        phys[:_BASE] = blk[:_BASE]
        s, v, off = blk[_BASE:]
        out.append(_rk4(_KIND[kind], t, phys, float(s), float(v), float(v_s), int(substeps)) + off)
    return np.concatenate(out)


def _fit(kind: str, starts: list[np.ndarray], segs, y: np.ndarray, v_s: float, substeps: int, max_nfev: int):
    from scipy.optimize import least_squares

    def resid(P: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            r = _simulate(kind, P, segs, v_s, substeps) - y
        return np.where(np.isfinite(r), np.clip(r, -1e6, 1e6), 1e6)

    opts: dict[str, Any] = {}
    if len(segs) > 1:  # a segment's parameters move its own samples only: perturb the segments' together
        n_law, blocks = _layout(kind, len(segs))
        sparsity = np.zeros((len(y), blocks[-1].stop), np.int8)
        sparsity[:, :n_law] = 1
        row = 0
        for (t, _), sl in zip(segs, blocks):
            sparsity[row : row + len(t), sl] = 1
            row += len(t)
        opts["jac_sparsity"] = sparsity
    best = None
    for P0 in starts:
        o = least_squares(resid, P0, x_scale="jac", max_nfev=max_nfev, **opts)
        if best is None or o.cost < best.cost:
            best = o
    return 2.0 * float(best.cost), best.x, best.fun


def _whole_segments(res: Any, e: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each segment's times and unsmoothed chart positions along ``e``, edges included (the residual's samples stop
    short of them, and a decay's largest amplitudes are at its start): the segment states'
    :attr:`~lagsplat.diagnose.residual_data.SegmentState.whole` samples, or the residual's own without states."""
    states = getattr(res, "states", None) or []
    if states:
        return [(st.t[st.whole].astype(np.float64), st.q_raw[st.whole] @ e) for st in states]
    return [(res.t[idx].astype(np.float64), res.q_raw[idx] @ e) for idx in res.segment_slices()]


def law_evidence(record: Mapping[str, Any] | None, law: str, practical_only: bool = True) -> float:
    """The evidence a :func:`decay_law` record gives ``law`` (``"dry"`` or ``"drag"``) over a viscous decay; ``-inf``
    where the law was not read, its coefficient took the opposite law's sign or (``practical_only``) it removes less
    than :data:`MIN_LOSS_PER_PERIOD` of the amplitude per period (a record without the size counts as practical).
    One reading for the candidates' support and the report's line."""
    rec = (record or {}).get(law) or {}
    v = float(rec.get("evidence", -math.inf))
    if practical_only and not rec.get("practical", True):
        return -math.inf
    return v if rec.get("sign_ok") and math.isfinite(v) else -math.inf


def decay_law(res: Any, e: np.ndarray, substeps: int = 2, max_nfev: int = 200) -> dict[str, Any]:
    """Evidence of the whole training trajectory for a dry-friction or a quadratic-drag decay over a viscous one.

    Args:
        res: the :class:`~lagsplat.diagnose.residual_data.Residual` (its segments, times and the chart's
            unsmoothed positions ``q_raw``).
        e: ``[d]`` unit direction the positions are read along.
        substeps: RK4 steps per frame interval.
        max_nfev: residual evaluations per least-squares start.

    Returns:
        ``{}`` where the law is not read (``d > 1``, a varying input, or no segment of at least two
        periods); else ``{"n": samples, "n_eff": effective samples, "rho": lag-one autocorrelation, "n_segments": segments read,
        "rms_viscous": rms misfit of the viscous fit (latent units), "dry": {"evidence", "coef", "sign_ok",
        "loss_per_period", "practical"}, "drag": {...}}``; ``evidence`` on the ``Delta BIC`` scale, ``coef`` the
        law's coefficient (``mu``, ``c2``; latent units), ``sign_ok`` whether it is positive: a negative one buys
        the opposite law and is no evidence for this one (see the module docstring); ``loss_per_period`` the
        amplitude the law alone removes per period relative to the largest amplitude, ``practical`` whether
        that reaches :data:`MIN_LOSS_PER_PERIOD`.
    """
    if res.d != 1 or (res.u.size and float(np.ptp(res.u, axis=0).max()) > 0):
        return {}
    f = float(res.f_dominant_hz)
    if not (f > 0):
        return {}
    segs = []
    for t, s in _whole_segments(res, np.asarray(e, np.float64)):
        if len(t) > 8 and (t[-1] - t[0]) * f >= _MIN_PERIODS:
            segs.append((t, s))
    if not segs:
        return {}
    y = np.concatenate([s for _, s in segs])
    w = 2.0 * math.pi * f
    amp = float(max(np.ptp(s) for _, s in segs)) / 2.0
    v_s = 0.02 * w * amp
    starts = [np.concatenate([np.r_[w * w, z * w, np.zeros(_BASE - 2), s[0] - float(np.median(s)), float(np.gradient(s, t)[0]), float(np.median(s))]
                              for t, s in segs]) for z in (0.01, 0.05)]  # fmt: skip
    ssr0, P0, r0 = _fit("viscous", starts, segs, y, v_s, substeps, max_nfev)
    scale = {"dry": 0.01 * w * w * amp, "drag": 0.1 * w / max(amp, 1e-12)}
    fits = {law: _fit(law, [np.r_[g * scale[law], P0] for g in (0.0, 1.0)], segs, y, v_s, substeps, max_nfev) for law in LAWS}
    # the viscous fit once more from each law's optimum without its term, so that nested fits are compared at their optima
    again = _fit("viscous", [P[1:] for _, P, _ in fits.values()], segs, y, v_s, substeps, max_nfev)
    if again[0] < ssr0:
        ssr0, P0, r0 = again
    n = len(y)
    rho = float(np.clip(np.corrcoef(r0[1:], r0[:-1])[0, 1], 0.0, 0.95)) if n > 3 and r0.std() > 0 else 0.0
    n_eff = n * (1.0 - rho) / (1.0 + rho)
    out: dict[str, Any] = {"n": n, "n_eff": n_eff, "rho": rho, "rms_viscous": math.sqrt(ssr0 / n), "n_segments": len(segs)}
    for law in LAWS:
        ssr, P, _ = fits[law]
        ev = n_eff * math.log(max(ssr0, 1e-300) / max(ssr, 1e-300)) - math.log(max(n_eff, 1.0))
        coef = float(P[0])
        loss = 4.0 * coef / (w * w * max(amp, 1e-12)) if law == "dry" else 8.0 / 3.0 * coef * amp
        out[law] = {"evidence": float(ev), "coef": coef, "sign_ok": coef > 0, "loss_per_period": float(loss),
                    "practical": bool(loss >= MIN_LOSS_PER_PERIOD)}  # fmt: skip
    return out

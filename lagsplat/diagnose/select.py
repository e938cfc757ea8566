"""Which unmodelled effect explains the residual: fit, rank, test, and collect the evidence.

Every candidate of :mod:`lagsplat.diagnose.effects` is fitted to the residual
generalized force ``r`` of :mod:`lagsplat.diagnose.residual` by linear least
squares in its coefficients, profiled over a grid of its few nonlinear
parameters (and, for ``d > 1``, over latent directions).

Nuisance terms
--------------
A fitted model that misses an effect compensates for it with what it has: a
Coulomb friction shows as extra viscous damping, a hardening spring as extra
stiffness. Each fit therefore includes *model-class* terms, and a candidate is
judged by what it explains *beyond* them (the null hypothesis "nothing
significant" is the nuisance fit alone). Two regressions share the work:

* **out-of-class** candidates (friction, drag, periodic force, drift, delay,
  missing DOF), which no setting of the Lagrangian can produce, are fitted to
  the residual of the *fitted model*, smoothed 1.5x wider than the in-class
  one (:attr:`Residual.wide <lagsplat.diagnose.residual.Residual.wide>`, see
  "Band of the out-of-class regression" below). The nuisance is linear in the state,
  ``r ~ dK q + dC qdot + f_0 (+ dB u)`` (free ``[d,d]`` matrices, one offset),
  plus the in-class corrections a convex potential, a position-dependent
  inertia and the input map ``b(q)`` could still make (centred ``q`` monomials
  of degree 2 and 3; ``qdot_i qdot_j`` and ``q_k qdot_i qdot_j``; ``u_j q_i``),
  so that a model learned slightly wrong within its own class (or a chart
  that is a nonlinear function of the physical coordinate) is not taken for
  an effect it lacks;
* **in-class** candidates (:attr:`~lagsplat.diagnose.effects.Effect.in_class`:
  cubic stiffness, end stop), which a convex potential can partly absorb, are
  fitted to the residual of the model's *linearisation* on the data (its
  force minus its least-squares fit by the linear nuisance, added back to
  ``r``), with the linear and inertia nuisance: the effect is then seen in full,
  whether the model absorbed part of it or mis-learned it. They must also
  reach a physical size (:meth:`~lagsplat.diagnose.effects.Effect.practical`).

Residuals are weighted by the per-coordinate noise level (:attr:`Residual.noise_r`).

Band of the out-of-class regression
-----------------------------------
The Lagrangian class of the paper dissipates only through the Rayleigh
function ``1/2 qdot^T C(q) qdot`` (§3.3, "Dissipation"); what falls outside
(§5, "Limitations") and is in the library beyond it is mostly *slow*. A
quadratic drag ``-c2 |qdot| qdot`` or a dry friction is, at one amplitude,
almost a viscous damping (``|sin| sin`` is 98 % correlated with ``sin``): the
model's fitted ``C`` takes the mean, and what is left is the dependence of
the decay rate on the amplitude (the envelope is hyperbolic or linear, not
exponential), a modulation of the fundamental over the recording. At the
default smoothing (``period / 12``) the twice-differentiated chart noise peaks
near the 3rd harmonic and dominates the residual's variance, so ``R2``,
``Delta BIC`` and the CV gain of such an effect are diluted by noise where it
has no power. Out-of-class candidates are therefore fitted to the residual at
``1.5 x`` the smoothing (``period / 8``: noise variance 7.6x lower, the
fundamental still at 73 %), while the in-class candidates, whose signature is
the waveform (an end stop's one-sided spike, a Duffing 3rd harmonic), keep
the sharp residual. Both regressions keep their own null, noise level and
sample spacing, and the ranking compares their ``Delta BIC``. The reported
``null`` (``excess_over_noise``, ``unexplained``, the nuisance corrections) is
that of the sharp residual, as the localisation reads it; ``null["out_of_class"]``
is the null of the wide regression. Example (blind suite, cheap budget with Stage 2 at 60 epochs,
32 x 32 px, ``benchmarks/diagnosis.py``): ``pendulum-quadratic_drag-0`` / ``-1``,
whose drag causes 76 % / 81 % of the energy loss per cycle at the nominal
amplitude, were missed (Delta BIC 0.9 / 5.5, R2 0.035 / 0.054) and are found
at the wider smoothing (Delta BIC 19 / 41, R2 0.19 / 0.30, CV gain 0.20 / 0.28).

Ranking and significance
------------------------
Candidates are ranked by the Bayesian information criterion (Schwarz 1978)
with a Gaussian likelihood of unknown variance,

    BIC = N_eff log(SSR / N) + k log N_eff,   N_eff = N / spacing,

``k`` counting the linear coefficients, the profiled nonlinear parameters and
the direction; ``spacing`` (2 sigma frames) accounts for the correlation the
smoothing puts between neighbouring residual samples. A candidate *wins* only
if it is physical (sign-constrained coefficients are fitted by non-negative
least squares, :func:`scipy.optimize.nnls`), of physical size (in-class
candidates) and passes all of

* ``Delta BIC = BIC_null - BIC >= min_delta_bic`` (10: "very strong" evidence,
  Kass & Raftery, JASA 90, 1995),
* ``R2 = 1 - SSR / SSR_null >= min_r2``: it explains a noticeable share of what
  the model leaves (effect size, so that a long clean clip does not promote a
  negligible misfit),
* a blocked cross-validation gain ``1 - CV_SSE / CV_SSE_null >= min_cv_gain``
  (contiguous blocks of about two periods, ``n_folds`` interleaved folds; the
  nonlinear parameters are the ones chosen on all data).

Otherwise the verdict is ``"none"`` ("nothing significant"). With
``max_effects > 1`` the search is repeated with the winners' features added
to the nuisance (greedy forward selection).

Evidence
--------
:func:`signatures` reads the physical signatures off the trajectory: the
envelope of the free decay (linear: dry friction; exponential: viscous;
hyperbolic: quadratic drag), the dependence of the period-by-period frequency on
amplitude (Duffing: hardening / softening, end stop) and on time (drift), and
the residual's spectral peaks against the model's modal frequencies (periodic
force, missing degree of freedom).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import nnls

from lagsplat.diagnose.effects import EFFECTS, Effect, get_effect
from lagsplat.diagnose.residual import Residual
from lagsplat.diagnose.signatures import directions, signatures
from lagsplat.io.common import jsonable

__all__ = ["CandidateFit", "Diagnosis", "select_effect"]


@dataclass
class CandidateFit:
    """One candidate fitted at its best nonlinear parameters.

    Attributes:
        effect: candidate name (``"none"`` for the null fit).
        params: chosen nonlinear parameters.
        direction: ``[d]`` unit latent direction the effect acts along.
        names: coefficient names; ``coef``, ``se``: ``[p]`` values and standard errors
            (generalized-force units of the model).
        ssr: weighted sum of squared residuals (noise units); ``k``: parameter count.
        bic: information criterion; ``delta_bic``: ``BIC_null - bic`` (higher is better).
        r2: share of the null residual explained; ``cv_gain``: blocked-CV gain over the null.
        physical: sign constraints satisfied (and the fit is not degenerate).
        significant: passes the significance rule (see module docstring).
        practical: large enough physically (:meth:`Effect.practical`; always true for out-of-class effects).
        force: ``[n,d]`` fitted effect force on the residual samples (not serialised).
        design: ``[n d, p]`` the candidate's stacked, noise-weighted regression columns on the residual
            it was fitted to (the wide one for out-of-class candidates; not serialised).
        interpretation: physical reading (:meth:`Effect.interpret`).
    """

    effect: str
    params: dict[str, Any]
    direction: np.ndarray
    names: list[str]
    coef: np.ndarray
    se: np.ndarray
    ssr: float
    k: int
    bic: float
    delta_bic: float = 0.0
    r2: float = 0.0
    cv_gain: float = 0.0
    physical: bool = True
    significant: bool = False
    practical: bool = True
    force: np.ndarray | None = field(default=None, repr=False)
    design: np.ndarray | None = field(default=None, repr=False)
    interpretation: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable record (without the per-sample force)."""
        return {
            "effect": self.effect,
            "params": jsonable(self.params),
            "direction": [float(v) for v in self.direction],
            "coefficients": {n: {"value": float(c), "se": float(s)} for n, c, s in zip(self.names, self.coef, self.se)},
            "ssr": float(self.ssr),
            "k": int(self.k),
            "bic": float(self.bic),
            "delta_bic": float(self.delta_bic),
            "r2": float(self.r2),
            "cv_gain": float(self.cv_gain),
            "physical": bool(self.physical),
            "practical": bool(self.practical),
            "significant": bool(self.significant),
            "interpretation": jsonable(self.interpretation),
        }


@dataclass
class Diagnosis:
    """The verdict of :func:`select_effect`.

    Attributes:
        winner: name of the first accepted effect, or ``"none"`` (nothing significant).
        effects: accepted effects in the order found (greedy forward selection).
        ranking: every candidate of the first round, best ``delta_bic`` first.
        null: the nuisance-only fit on the (sharp) residual (``ssr``, ``bic``,
            ``excess_over_noise`` = SSR / N: about 1 when the residual is consistent
            with the chart noise; ``excess_after_effects``, ``unexplained`` and
            ``warning`` for what the accepted effects leave; ``linearised``: the null of
            the in-class regression; ``out_of_class``: the null of the out-of-class
            regression on the wide residual, with its ``sigma_frames``).
        evidence: :func:`signatures`.
        nuisance: the model-class corrections of the null fit (``dK``, ``dC``, ``f0``).
        settings: thresholds and counts used.
    """

    winner: str
    effects: list[CandidateFit]
    ranking: list[CandidateFit]
    null: dict[str, Any]
    evidence: dict[str, Any]
    nuisance: dict[str, Any]
    settings: dict[str, Any]

    @property
    def labels(self) -> list[str]:
        """Names of the accepted effects (empty when nothing is significant)."""
        return [f.effect for f in self.effects]

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable record (for ``report.json``)."""
        return {
            "winner": self.winner,
            "effects": [f.to_dict() for f in self.effects],
            "ranking": [f.to_dict() for f in self.ranking],
            "null": jsonable(self.null),
            "evidence": jsonable(self.evidence),
            "nuisance": jsonable(self.nuisance),
            "settings": jsonable(self.settings),
        }

    def summary(self) -> str:
        """A few lines of text: the verdict, the ranking and the evidence."""
        lines = [f"verdict: {self.winner if self.winner != 'none' else 'nothing significant'}"]
        for f in self.effects:
            lines.append(f"  {f.effect}: dBIC = {f.delta_bic:.1f}, R2 = {f.r2:.2f}, CV gain = {f.cv_gain:.2f}; {f.interpretation.get('text', '')}")
        lines.append(f"residual / noise (null) = {self.null['excess_over_noise']:.2f}")
        if self.null.get("warning"):
            lines.append("warning: " + self.null["warning"])
        lines.append("ranking: " + ", ".join(f"{f.effect} ({f.delta_bic:.1f}{'' if f.physical else ', unphysical'})" for f in self.ranking))
        ev = self.evidence
        if "envelope" in ev and ev["envelope"].get("best"):
            lines.append(f"envelope decay: best {ev['envelope']['best']}")
        if "frequency" in ev and "slope_amp2" in ev["frequency"]:
            fr = ev["frequency"]
            lines.append(f"frequency vs amplitude^2: z = {fr['z_amp2']:.1f}; vs time: z = {fr['z_time']:.1f}")
        if ev.get("spectrum", {}).get("unexplained_peaks_hz"):
            lines.append("residual peaks the model lacks (Hz): " + ", ".join(f"{p:.3g}" for p in ev["spectrum"]["unexplained_peaks_hz"]))
        return "\n".join(lines)


# ---------------------------------------------------------------------- least squares
def _linear_features(res: Residual) -> np.ndarray:
    """Model-class nuisance ``[n, 2d + 1 + n_u]``: the smoothed ``q, qdot, 1, u``.

    A linear force commutes with the smoothing (``G * (K q) = K (G * q)``), so these
    columns are exactly how an error of the model's linear terms shows in ``r``.
    """
    return np.concatenate([res.q, res.qdot, np.ones((res.n, 1)), res.u], 1)


def _poly_features(res: Residual, parts: tuple[str, ...] = ("potential", "inertia", "input")) -> np.ndarray:
    """In-class corrections of the fitted model.

    * monomials of degree 2 and 3 of the centred ``q`` (all for ``d <= 3``, else
      per coordinate): the potential a convex ``V`` can still bend to;
    * ``qdot_i qdot_j`` and ``(q_k - q_bar_k) qdot_i qdot_j``: the Coriolis /
      centrifugal forces ``-(dM/dq) qdot qdot`` of a position-dependent inertia
      (paper §3.3, "Inertia"), which is also what a chart that is a nonlinear
      function of the physical coordinate produces;
    * with actuation, ``u_j (q_i - q_bar_i)``: the position dependence of the input map ``b(q)`` (paper Eq. 6).
    """
    from itertools import combinations_with_replacement

    d = res.d
    mu = res.q.mean(0)
    small = d <= 3
    combos = [c for k in (2, 3) for c in combinations_with_replacement(range(d), k)] if small else [(i,) * k for k in (2, 3) for i in range(d)]
    pairs = list(combinations_with_replacement(range(d), 2)) if small else [(i, i) for i in range(d)]

    def phi(st):
        x = st.q - mu
        v = st.qdot
        cols = [np.prod(x[:, list(c)], axis=1) for c in combos] if "potential" in parts else []
        if "inertia" in parts:
            vv = [v[:, i] * v[:, j] for i, j in pairs]
            cols += vv
            cols += [x[:, k] * w for w in vv for k in range(d)] if small else [x[:, i] * v[:, i] ** 2 for i in range(d)]
        if "input" in parts:
            cols += [st.u[:, j] * x[:, i] for j in range(st.u.shape[1]) for i in range(d)]
        return np.stack(cols, 1) if cols else np.zeros((len(st.t), 0))

    return res.features(phi)


class _Problem:
    """Stacked weighted regression ``vec(target / noise) ~ Z_nuisance a + Z_candidate w``.

    ``target`` is the residual (``[n,d]``); the nuisance is the linear model-class
    terms, plus (``poly``) the in-class potential corrections of degree 2 and 3.
    """

    def __init__(self, res: Residual, folds: np.ndarray, target: np.ndarray, X_lin: np.ndarray, poly: tuple[str, ...]) -> None:
        self.res = res
        d, n = res.d, res.n
        self.w = 1.0 / res.noise_r  # [d]
        self.y = (target * self.w[None]).T.reshape(-1)  # output-major stacking
        self.N = n * d
        X0 = np.concatenate([X_lin, _poly_features(res, poly)], 1) if poly else X_lin
        self.p0 = X0.shape[1]
        self.p_lin = X_lin.shape[1]
        Z = np.zeros((self.N, self.p0 * d))
        for j in range(d):
            Z[j * n : (j + 1) * n, j * self.p0 : (j + 1) * self.p0] = X0 * self.w[j]
        self.Zn = Z
        self.folds = np.tile(folds, d)
        self._refresh()

    def _refresh(self) -> None:
        self.Q, _ = np.linalg.qr(self.Zn / np.maximum(np.linalg.norm(self.Zn, axis=0), 1e-300))
        self.r0 = self.y - self.Q @ (self.Q.T @ self.y)
        self.pn = self.Zn.shape[1]

    def add_nuisance(self, Zc: np.ndarray) -> None:
        """Absorb an accepted effect's columns into the nuisance."""
        self.Zn = np.concatenate([self.Zn, Zc], 1)
        self._refresh()

    def stack(self, X: np.ndarray, e: np.ndarray) -> np.ndarray:
        """Candidate features ``[n,p]`` along direction ``e`` -> stacked ``[N,p]``."""
        return np.concatenate([X * (e[j] * self.w[j]) for j in range(self.res.d)], 0)

    def fit(self, Zc: np.ndarray, positive: bool) -> tuple[np.ndarray, float, np.ndarray]:
        """``(w [p], ssr, Zc_projected)`` of the candidate on the nuisance-projected residual."""
        Zt = Zc - self.Q @ (self.Q.T @ Zc)
        nrm = np.linalg.norm(Zt, axis=0)
        ok = nrm > 1e-9 * max(1.0, float(np.linalg.norm(Zc)))
        w = np.zeros(Zc.shape[1])
        if ok.any():
            A = Zt[:, ok] / nrm[ok]
            if positive:
                sol, _ = nnls(A, self.r0)
            else:
                sol = np.linalg.lstsq(A, self.r0, rcond=None)[0]
            w[ok] = sol / nrm[ok]
        res = self.r0 - Zt @ w
        return w, float(res @ res), Zt

    def bic(self, ssr: float, k: int) -> float:
        n_eff = self.N / self.res.spacing
        return n_eff * math.log(max(ssr, 1e-300) / self.N) + k * math.log(n_eff)

    def cv_sse(self, Zc: np.ndarray | None, positive: bool) -> float:
        """Blocked cross-validation SSE of nuisance (+ candidate) fits."""
        Z = self.Zn if Zc is None else np.concatenate([self.Zn, Zc], 1)
        sse = 0.0
        for f in np.unique(self.folds):
            tr, te = self.folds != f, self.folds == f
            A = Z[tr]
            scale = np.maximum(np.linalg.norm(A, axis=0), 1e-300)
            if positive and Zc is not None:
                # nuisance free, candidate >= 0: project the nuisance out within the training rows
                Zn_tr, Zc_tr = self.Zn[tr] / scale[: self.pn], Zc[tr] / scale[self.pn :]
                Qt, _ = np.linalg.qr(Zn_tr)
                Zct = Zc_tr - Qt @ (Qt.T @ Zc_tr)
                yt = self.y[tr] - Qt @ (Qt.T @ self.y[tr])
                wc, _ = nnls(Zct, yt) if Zct.shape[1] else (np.zeros(0), 0.0)
                an = np.linalg.lstsq(Zn_tr, self.y[tr] - Zc_tr @ wc, rcond=None)[0]
                coef = np.concatenate([an, wc]) / scale
            else:
                coef = np.linalg.lstsq(A / scale, self.y[tr], rcond=None)[0] / scale
            e = self.y[te] - Z[te] @ coef
            sse += float(e @ e)
        return sse


def _folds(res: Residual, n_folds: int, block_s: float | None) -> np.ndarray:
    """Interleaved fold label of each residual sample: contiguous blocks of ``block_s`` seconds."""
    if block_s is None:
        f = res.f_dominant_hz
        block_s = 2.0 / f if math.isfinite(f) and f > 0 else 40 * res.dt
    L = max(8, int(round(block_s / res.dt)))
    out = np.empty(res.n, int)
    b = 0
    for idx in res.segment_slices():
        nb = max(1, len(idx) // L)
        blk = np.minimum(np.arange(len(idx)) * nb // len(idx), nb - 1)
        out[idx] = (b + blk) % n_folds
        b += nb
    return out


def _scales(res: Residual, e: np.ndarray) -> dict[str, float]:
    """Linear stiffness / damping of the model along ``e`` (regression of its force on q, qdot) and data scales."""
    s, v = res.q @ e, res.qdot @ e
    X = np.stack([s - s.mean(), v, np.ones_like(s)], 1)
    f = res.f_model @ e
    coef = np.linalg.lstsq(X, f, rcond=None)[0]
    return {
        "k": float(-coef[0]), "c": float(-coef[1]), "s_rms": float(np.std(s)), "s_raw_rms": float(np.std(res.q_raw @ e)),
        "sdot_rms": float(np.sqrt(np.mean(v**2))),
        "s_bar": float(s.mean()), "t_bar": float(np.mean(res.t)),
    }  # fmt: skip


def _design(prob: _Problem, fit: CandidateFit) -> np.ndarray:
    """A fitted candidate's stacked columns on ``prob``'s own residual (its features at the fit's parameters and direction)."""
    eff = get_effect(fit.effect)
    phi, _ = eff.feature(prob.res, fit.direction, fit.params)
    return prob.stack(prob.res.features(phi), fit.direction)


def _fit_candidate(prob: _Problem, eff: Effect, dirs: Sequence[np.ndarray], extra_k: int, thresholds: dict[str, float]) -> CandidateFit | None:
    """Profile one candidate over its grid and directions; the best fit with standard errors."""
    res = prob.res
    best: tuple[float, Any] | None = None

    def scan(e: np.ndarray, grid: list[dict[str, Any]]) -> None:
        nonlocal best
        for params in grid:
            phi, names = eff.feature(res, e, params)
            X = res.features(phi)
            Zc = prob.stack(X, e)
            w, ssr, Zt = prob.fit(Zc, eff.positive)
            if best is None or ssr < best[0]:
                best = (ssr, (e, params, names, X, Zc, w, Zt))

    for e in dirs:
        r0e = (prob.r0.reshape(res.d, res.n) / prob.w[:, None]).T @ e  # nuisance-free residual along e (force units)
        scan(e, eff.grid(res, e, r0e))
    if best is None:
        return None
    e_best, p_best = best[1][0], best[1][1]
    scan(e_best, eff.refine(res, e_best, p_best))
    ssr, (e, params, names, X, Zc, w, Zt) = best
    p = len(w)
    k = prob.pn + p + eff.n_nonlinear + extra_k
    dof = max(prob.N - prob.pn - p, 1)
    s2 = ssr / dof
    try:
        cov = s2 * res.spacing * np.linalg.pinv(Zt.T @ Zt)
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        se = np.full(p, np.nan)
    physical = bool(np.any(w != 0)) and (not eff.positive or bool(np.all(w >= 0)))
    fit = CandidateFit(eff.name, params, e, names, w, se, ssr, k, prob.bic(ssr, k), physical=physical)
    fit.force = (X @ w)[:, None] * e[None, :]
    fit.design = Zc
    fit.interpretation = eff.interpret(w, se, params, res, e, _scales(res, e))
    ok, why = eff.practical(fit.interpretation, thresholds)
    fit.practical = ok
    if not ok:
        fit.interpretation["below_practical_size"] = why
    fit.interpretation["fitted_against"] = "model linearisation" if eff.in_class else "fitted model"
    return fit


def select_effect(
    res: Residual,
    candidates: Sequence[str] | None = None,
    *,
    min_delta_bic: float = 10.0,
    min_r2: float = 0.1,
    min_cv_gain: float = 0.02,
    min_cubic_shift: float = 0.03,
    min_stop_stiffness_ratio: float = 2.0,
    min_periodic_response: float = 0.01,
    max_effects: int = 1,
    n_folds: int = 5,
    block_s: float | None = None,
    model_freqs_hz: Sequence[float] | None = None,
    unexplained_excess: float = 4.0,
) -> Diagnosis:
    """Fit every candidate effect to the residual, rank them and decide (see the module docstring).

    Two regressions share the work:

    * out-of-class candidates (friction, drag, periodic force, drift, delay,
      missing DOF) are fitted to the residual of the *fitted model*, at the wider
      smoothing of :attr:`Residual.wide <lagsplat.diagnose.residual.Residual.wide>`
      when it is there (see "Band of the out-of-class regression" in the module
      docstring), with the linear nuisance plus the in-class corrections (potential: centred ``q``
      monomials of degree 2 and 3; inertia: ``qdot qdot`` and ``q qdot qdot``;
      input map: ``u q``), so that a model learned slightly wrong within its
      own class is not mistaken for an effect it lacks;
    * in-class candidates (:attr:`Effect.in_class`: cubic stiffness, end stop),
      which a convex potential can partly absorb, are fitted to the residual of
      the model's *linearisation* (the model's force minus its regression on
      the linear nuisance, added back), with the linear and inertia nuisance;
      they must also reach a physical size (``min_cubic_shift``: relative
      frequency shift at the largest amplitude; ``min_stop_stiffness_ratio``:
      stop stiffness over the spring's). A cubic stiffness must moreover show in
      the recorded *timing*: the frequency-vs-amplitude^2 shift of the evidence
      (zero-crossing periods, which no monotone chart changes) must have the
      sign of ``k3`` and at least half the practical size, since a chart that
      stretches large excursions makes an isochronous oscillation look
      anharmonic in ``q`` but leaves its period alone. A periodic force must
      drive a motion of at least ``min_periodic_response`` (1 %) of the recorded
      one: coherent over the whole clip, a far smaller one is still
      significant, but changes nothing the video shows.

    Args:
        res: the residual (:func:`~lagsplat.diagnose.residual.residual_force`), normally
            on training frames only, so that held-out frames stay untouched for the gap;
            its :attr:`~lagsplat.diagnose.residual.Residual.wide` (if any) is the one the
            out-of-class candidates are fitted to.
        candidates: names to test (default: every applicable one of
            :data:`~lagsplat.diagnose.effects.EFFECTS`).
        min_delta_bic, min_r2, min_cv_gain: the statistical significance rule.
        min_cubic_shift, min_stop_stiffness_ratio: physical size of in-class effects.
        min_periodic_response: physical size of a periodic force: the rms motion it drives
            off resonance (``amplitude / (k |1 - (f / f_motion)^2|) / sqrt 2``) over the rms of
            the recorded motion along its direction.
        max_effects: how many effects greedy forward selection may accept.
        n_folds: folds of the blocked cross-validation.
        block_s: cross-validation block length, s (default two dominant periods).
        model_freqs_hz: the model's modal frequencies (excluded, with their harmonics and
            combination tones, from the periodic-force and hidden-mode search; spectrum evidence).
        unexplained_excess: ``null["unexplained"]`` (and a ``warning``) is set when the
            residual left after the nuisance and the accepted effects exceeds this many
            times the chart-noise variance.

    Returns:
        The :class:`Diagnosis`.

    Raises:
        KeyError: on an unknown candidate name.
        ValueError: if the residual has too few samples for the nuisance fit.
    """
    wide = res.wide if res.wide is not None and res.wide.n > 2 * (2 * res.d + 1 + res.n_u + 9) + 4 else res
    if model_freqs_hz is not None:
        res.meta["model_freqs_hz"] = [float(f) for f in model_freqs_hz]
        wide.meta["model_freqs_hz"] = [float(f) for f in model_freqs_hz]
    effs = [get_effect(c) for c in candidates] if candidates is not None else list(EFFECTS)
    effs = [e for e in effs if e.applicable(res)]
    thresholds = {"min_cubic_shift": min_cubic_shift, "min_stop_stiffness_ratio": min_stop_stiffness_ratio,
                  "min_periodic_response": min_periodic_response}  # fmt: skip
    # the chart-invariant signatures, read before the fits: a cubic stiffness must also show in the timing
    ev = signatures(res, model_freqs_hz=model_freqs_hz)
    res.meta["frequency_signature"] = ev["frequency"]
    probs, prob_null, prob_model = _problems(res, wide, n_folds, block_s)
    dirs = {k: directions(p.res) for k, p in probs.items()}
    nuisance, null = _null_summary(res, wide, probs, prob_null)

    accepted: list[CandidateFit] = []
    ranking: list[CandidateFit] = []
    remaining = list(effs)
    for round_ in range(max(1, int(max_effects))):
        fits = _fit_candidates(remaining, probs, prob_model, dirs, res.d - 1, thresholds)  # fit, ranked by Delta BIC
        _rank(fits, probs, min_delta_bic, min_r2, min_cv_gain)  # cross-validate where it can matter, then decide
        if round_ == 0:
            ranking = fits
        win = next((f for f in fits if f.significant), None)
        if win is None:
            break
        accepted.append(win)
        for prob in {id(p): p for p in (*probs.values(), prob_null)}.values():
            prob.add_nuisance(win.design if prob is probs[get_effect(win.effect).in_class] else _design(prob, win))
        remaining = [e for e in remaining if e.name != win.effect]
        if not remaining:
            break
    _unexplained(null, prob_null, bool(accepted), unexplained_excess)
    settings = {
        "min_delta_bic": min_delta_bic, "min_r2": min_r2, "min_cv_gain": min_cv_gain, **thresholds, "max_effects": max_effects,
        "n_folds": n_folds, "candidates": [e.name for e in effs], "sigma_frames": res.sigma, "spacing": res.spacing,
        "n_samples": res.n, "n_segments": res.n_segments, "n_directions": len(dirs[True]),
        "sigma_frames_out_of_class": wide.sigma, "spacing_out_of_class": wide.spacing, "n_samples_out_of_class": wide.n,
    }  # fmt: skip
    return Diagnosis(accepted[0].effect if accepted else "none", accepted, ranking, null, ev, nuisance, settings)


def _problems(res: Residual, wide: Residual, n_folds: int, block_s: float | None) -> tuple[dict[bool, _Problem], _Problem, _Problem]:
    """The regressions of :func:`select_effect`: ``({in_class: problem}, null problem, model problem)``.

    Raises:
        ValueError: if the residual has too few samples for the nuisance fit.
    """
    folds = _folds(res, n_folds, block_s)
    X_lin = _linear_features(res)
    if res.n <= 2 * (X_lin.shape[1] + 9) + 4:
        raise ValueError(f"the residual has {res.n} samples for {X_lin.shape[1] + 9} nuisance coefficients per coordinate; need a longer trajectory")
    # the model's own nonlinear force on the data: its force minus its best linear fit on the nuisance
    beta = np.linalg.lstsq(X_lin, res.f_model, rcond=None)[0]
    g_nl = res.f_model - X_lin @ beta
    in_class_nuisance = ("inertia",)
    out_nuisance = ("potential", "inertia", "input")
    # the null on the sharp residual: what is reported (and what the localisation reads)
    prob_null = _Problem(res, folds, res.r, X_lin, out_nuisance)
    probs = {
        False: prob_null if wide is res else _Problem(wide, _folds(wide, n_folds, block_s), wide.r, _linear_features(wide), out_nuisance),
        True: _Problem(res, folds, res.r + g_nl, X_lin, in_class_nuisance),
    }
    prob_model = _Problem(res, folds, g_nl, X_lin, in_class_nuisance)  # what the model itself carries of an in-class effect
    return probs, prob_null, prob_model


def _null_of(prob: _Problem) -> dict[str, Any]:
    ssr = float(prob.r0 @ prob.r0)
    return {"ssr": ssr, "bic": prob.bic(ssr, prob.pn), "k": prob.pn, "N": prob.N, "excess_over_noise": ssr / prob.N}


def _null_summary(res: Residual, wide: Residual, probs: dict[bool, _Problem], pb: _Problem) -> tuple[dict[str, Any], dict[str, Any]]:
    """The fitted nuisance (linear corrections of the model) and the null hypothesis's fit statistics."""
    d = res.d
    coef0 = np.linalg.lstsq(pb.Zn, pb.y, rcond=None)[0].reshape(d, pb.p0) / pb.w[:, None]
    nuisance = {"dK": (-coef0[:, :d]).tolist(), "dC": (-coef0[:, d : 2 * d]).tolist(), "f0": coef0[:, 2 * d].tolist(),
                "dB": coef0[:, 2 * d + 1 : pb.p_lin].tolist(), "poly": coef0[:, pb.p_lin :].tolist()}  # fmt: skip
    null = {**_null_of(pb), "N_eff": pb.N / res.spacing, "linearised": _null_of(probs[True]),
            "out_of_class": {**_null_of(probs[False]), "sigma_frames": wide.sigma, "N_eff": probs[False].N / wide.spacing}}  # fmt: skip
    return nuisance, null


def _fit_candidates(remaining: list, probs: dict[bool, _Problem], prob_model: _Problem, dirs: dict, extra_k: int, thresholds: dict) -> list[CandidateFit]:
    """Fit each remaining effect to its regression; returns the fits sorted by decreasing Delta BIC."""
    ref = {k: (float(p.r0 @ p.r0), p.bic(float(p.r0 @ p.r0), p.pn)) for k, p in probs.items()}
    fits = []
    for eff in remaining:
        prob = probs[eff.in_class]
        fit = _fit_candidate(prob, eff, dirs[eff.in_class], extra_k, thresholds)
        if fit is None:
            continue
        fit.delta_bic = ref[eff.in_class][1] - fit.bic
        fit.r2 = 1.0 - fit.ssr / max(ref[eff.in_class][0], 1e-300)
        if eff.in_class:
            w_model, _, _ = prob_model.fit(fit.design, False)
            fit.interpretation["model_carries"] = [float(v) for v in w_model]
            fit.interpretation["model_share"] = [float(m / c) if c != 0 else float("nan") for m, c in zip(w_model, fit.coef)]
        fits.append(fit)
    fits.sort(key=lambda f: f.delta_bic, reverse=True)
    return fits


def _rank(fits: list[CandidateFit], probs: dict[bool, _Problem], min_delta_bic: float, min_r2: float, min_cv_gain: float) -> None:
    """Cross-validate where it can matter (the costly part: candidates passing the rest, and the top 3) and mark the significant fits."""
    cv_ref: dict[bool, float] = {}
    for i, fit in enumerate(fits):
        if not (i < 3 or (fit.physical and fit.delta_bic >= min_delta_bic and fit.r2 >= min_r2)):
            continue
        eff = get_effect(fit.effect)
        prob = probs[eff.in_class]
        if eff.in_class not in cv_ref:
            cv_ref[eff.in_class] = prob.cv_sse(None, False)
        fit.cv_gain = 1.0 - prob.cv_sse(fit.design, eff.positive) / max(cv_ref[eff.in_class], 1e-300)
    for fit in fits:
        fit.significant = (
            fit.physical and fit.practical
            and fit.delta_bic >= min_delta_bic and fit.r2 >= min_r2 and fit.cv_gain >= min_cv_gain
        )


def _unexplained(null: dict[str, Any], pb: _Problem, any_accepted: bool, unexplained_excess: float) -> None:
    """Record the residual left after the nuisance and the accepted effects, and warn when it stays far above the chart noise."""
    left = float(pb.r0 @ pb.r0) / pb.N  # after the nuisance and the accepted effects (sharp residual)
    null["excess_after_effects"] = left
    null["unexplained"] = bool(left > unexplained_excess)
    if null["unexplained"]:
        null["warning"] = (
            f"after the model-class corrections{' and the effects found' if any_accepted else ''} the residual is still "
            f"{math.sqrt(left):.1f}x the chart noise (rms) and no candidate explains it: the model misfits within its own "
            "class (e.g. a distorted chart: try stage2.mass=learned or a better Stage 1), or the effect is not in the library"
        )

"""The stacked, noise-weighted least-squares regression a candidate effect is fitted in, with its nuisance columns and CV folds.

:func:`lagsplat.diagnose.select.select_effect` fits every candidate of
:mod:`lagsplat.diagnose.effects` to the residual beyond *model-class*
nuisance terms (see "Nuisance terms" and "Ranking and significance" in
:mod:`lagsplat.diagnose.select`): the linear ones (:func:`linear_features`),
the in-class corrections of a convex potential, a position-dependent inertia
and the input map (:func:`poly_features`), stacked over the latent coordinates
with the noise weights of the residual (:class:`Regression`), and
cross-validated over contiguous blocks (:func:`blocked_folds`).
"""

from __future__ import annotations

import math
from functools import cached_property
from itertools import combinations_with_replacement

import numpy as np
from scipy.optimize import nnls

from lagsplat.diagnose.residual_data import Residual

__all__ = ["linear_features", "poly_features", "Regression", "blocked_folds", "n_cv_folds", "MIN_CV_BLOCKS"]


def linear_features(res: Residual) -> np.ndarray:
    """Model-class nuisance ``[n, 2d + 1 + n_u]``: the smoothed ``q, qdot, 1, u``.

    A linear force commutes with the smoothing (``G * (K q) = K (G * q)``), so these
    columns are exactly how an error of the model's linear terms shows in ``r``.
    """
    return np.concatenate([res.q, res.qdot, np.ones((res.n, 1)), res.u], 1)


def poly_features(res: Residual, parts: tuple[str, ...] = ("potential", "inertia", "input")) -> np.ndarray:
    """In-class corrections of the fitted model, float64 ``[n, p]`` (``p = 0`` when ``parts`` is empty).

    * monomials of degree 2 and 3 of the centred ``q`` (all for ``d <= 3``, else
      per coordinate; for ``d = 1`` also 4 and 5, two more coefficients): the
      potential a convex ``V`` can still bend to. A learned potential whose
      stiffness follows the amplitude a little differently from the recording's
      (a pendulum's ``1 - cos`` read through a chart) leaves a force a cubic does
      not follow, and on one decaying take that rest fits as a drift of the
      stiffness (on a realistic pendulum with dry friction, up to the cubic a
      drift led the friction by far; with the quintic terms the drift is not
      practical and the friction is significant;
      ``docs/experiments/code_comment_history.md``);
    * ``qdot_i qdot_j`` and ``(q_k - q_bar_k) qdot_i qdot_j``: the Coriolis /
      centrifugal forces ``-(dM/dq) qdot qdot`` of a position-dependent inertia
      (paper §3.3, "Inertia"), which is also what a chart that is a nonlinear
      function of the physical coordinate produces;
    * with actuation, ``u_j (q_i - q_bar_i)``: the position dependence of the input map ``b(q)`` (paper Eq. 6).
    """
    d = res.d
    mu = res.q.mean(0)
    small = d <= 3
    degrees = (2, 3, 4, 5) if d == 1 else (2, 3)
    combos = [c for k in degrees for c in combinations_with_replacement(range(d), k)] if small else [(i,) * k for k in degrees for i in range(d)]
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


class Regression:
    """Stacked weighted regression ``vec(target / noise) ~ Z_nuisance a + Z_candidate w``.

    ``target`` is the residual (``[n,d]``); the nuisance is the linear model-class
    terms, plus (``poly``) the in-class corrections of :func:`poly_features`.
    Rows are stacked output-major (coordinate ``j`` fills rows ``j n .. (j + 1) n``)
    and weighted by ``1 / noise_r[j]``, so sums of squares are in noise units.

    Args:
        res: the residual the regression is on (noise level, sample spacing, features).
        folds: int ``[n]`` cross-validation fold of each residual sample (:func:`blocked_folds`).
        target: ``[n,d]`` what is regressed (the residual, or the residual plus the model's
            nonlinear force for the in-class candidates).
        X_lin: ``[n, p_lin]`` the linear nuisance (:func:`linear_features`).
        poly: which :func:`poly_features` to add to the nuisance (empty: none).

    Attributes:
        w: ``[d]`` noise weights; y: ``[N]`` weighted stacked target, ``N = n d``.
        Zn: ``[N, pn]`` nuisance columns (accepted effects' columns appended by :meth:`add_nuisance`).
        p0, p_lin: nuisance columns per coordinate (all, linear only).
        r0: ``[N]`` the target after the nuisance is projected out.
    """

    def __init__(self, res: Residual, folds: np.ndarray, target: np.ndarray, X_lin: np.ndarray, poly: tuple[str, ...]) -> None:
        self.res = res
        d, n = res.d, res.n
        self.w = 1.0 / res.noise_r  # [d]
        self.y = (target * self.w[None]).T.reshape(-1)  # output-major stacking
        self.N = n * d
        X0 = np.concatenate([X_lin, poly_features(res, poly)], 1) if poly else X_lin
        self.p0 = X0.shape[1]
        self.p_lin = X_lin.shape[1]
        Z = np.zeros((self.N, self.p0 * d))
        for j in range(d):
            Z[j * n : (j + 1) * n, j * self.p0 : (j + 1) * self.p0] = X0 * self.w[j]
        self.Zn = Z
        self.folds = np.tile(folds, d)
        self._poly = [j * self.p0 + k for j in range(d) for k in range(self.p_lin, self.p0)]  # the in-class corrections' columns
        self._refresh()

    @cached_property
    def _poly_basis(self) -> np.ndarray:
        """Orthonormal basis ``[N, m]`` of the in-class corrections' columns (:meth:`cv_sse_own`; they never change,
        :meth:`add_nuisance` appends after them)."""
        P = self.Zn[:, self._poly]
        return np.linalg.qr(P / np.maximum(np.linalg.norm(P, axis=0), 1e-300))[0] if P.shape[1] else np.zeros((self.N, 0))

    def _refresh(self) -> None:
        self.Q, _ = np.linalg.qr(self.Zn / np.maximum(np.linalg.norm(self.Zn, axis=0), 1e-300))
        self.r0 = self.y - self.Q @ (self.Q.T @ self.y)
        self.pn = self.Zn.shape[1]
        self._own: tuple[np.ndarray, np.ndarray] | None = None  # cv_sse_own's target and nuisance, for this nuisance

    def _without_poly(self, A: np.ndarray) -> np.ndarray:
        """``A`` with the in-class corrections' columns projected out (on all samples)."""
        Qp = self._poly_basis
        return A - Qp @ (Qp.T @ A)

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
        """Schwarz's criterion ``N_eff log(SSR / N) + k log N_eff`` with ``N_eff = N / spacing``."""
        n_eff = self.N / self.res.spacing
        return n_eff * math.log(max(ssr, 1e-300) / self.N) + k * math.log(n_eff)

    def cv_sse(self, Zc: np.ndarray | None, positive: bool) -> float:
        """Blocked cross-validation SSE of nuisance (+ candidate) fits, every column refitted per fold; ``nan`` with a single fold."""
        if n_cv_folds(self.folds) < 2:
            return float("nan")
        return self._blocked_sse(self.y, self.Zn, Zc, positive)

    def cv_sse_own(self, Zc: np.ndarray | None, positive: bool) -> float:
        """:meth:`cv_sse` with the in-class corrections (:func:`poly_features`) projected out of the target and the
        other columns on all samples first (Frisch-Waugh-Lovell), the rest refitted per fold; ``nan`` with a single fold.

        Refitted per fold, those polynomials (the potential's monomials up to degree 5) extrapolate beyond the
        amplitudes of the training blocks (on a decay the first block holds the largest), and a candidate
        correlated with them on the training blocks moves that extrapolation: :meth:`cv_sse` then measures the
        polynomial's tail as much as the candidate. Held at their fit on the whole take, they leave the question
        whether the candidate's own coefficients, fitted on some blocks, predict the others (on a realistic pendulum
        with dry friction of ``benchmarks/realistic.py`` the friction's coefficient is stable over the folds and
        its CV gain turns from negative to positive with the polynomials held;
        ``docs/experiments/diagnosis_history.md``, ``docs/experiments/code_comment_history.md``).
        """
        if n_cv_folds(self.folds) < 2:
            return float("nan")
        if self._own is None:  # the same for the reference and every candidate: projected once per nuisance
            keep = np.ones(self.Zn.shape[1], bool)
            keep[self._poly] = False
            self._own = (self._without_poly(self.y), self._without_poly(self.Zn[:, keep]))
        y, Zn = self._own
        return self._blocked_sse(y, Zn, None if Zc is None else self._without_poly(Zc), positive)

    def _blocked_sse(self, y: np.ndarray, Zn: np.ndarray, Zc: np.ndarray | None, positive: bool = False) -> float:
        """Sum over folds of the held-out SSE of ``y ~ Zn a + Zc w`` fitted on the other folds (``w >= 0`` if ``positive``)."""
        pn = Zn.shape[1]
        Z = Zn if Zc is None else np.concatenate([Zn, Zc], 1)
        sse = 0.0
        for f in np.unique(self.folds):
            tr, te = self.folds != f, self.folds == f
            scale = np.maximum(np.linalg.norm(Z[tr], axis=0), 1e-300)
            if positive and Zc is not None:
                # nuisance free, candidate >= 0: project the nuisance out within the training rows
                Zn_tr, Zc_tr = Zn[tr] / scale[:pn], Zc[tr] / scale[pn:]
                Qt, _ = np.linalg.qr(Zn_tr)
                Zct = Zc_tr - Qt @ (Qt.T @ Zc_tr)
                yt = y[tr] - Qt @ (Qt.T @ y[tr])
                wc, _ = nnls(Zct, yt) if Zct.shape[1] else (np.zeros(0), 0.0)
                an = np.linalg.lstsq(Zn_tr, y[tr] - Zc_tr @ wc, rcond=None)[0]
                coef = np.concatenate([an, wc]) / scale
            else:
                coef = np.linalg.lstsq(Z[tr] / scale, y[tr], rcond=None)[0] / scale
            e = y[te] - Z[te] @ coef
            sse += float(e @ e)
        return sse


#: Fewest contiguous blocks the cross-validation deals into folds: with fewer (a training part
#: shorter than about six periods at two periods a block), the blocks shrink to reach it.
MIN_CV_BLOCKS = 3
#: Shortest block, samples.
MIN_BLOCK_SAMPLES = 8


def blocked_folds(res: Residual, n_folds: int, block_s: float | None) -> np.ndarray:
    """Interleaved fold label of each residual sample: contiguous blocks of ``block_s`` seconds.

    Args:
        res: the residual (its segments, frame interval and dominant frequency).
        n_folds: number of folds; blocks are dealt to them in turn across segments.
        block_s: block length, s (default two dominant periods, or 40 frames without one,
            shortened on a short residual so that there are at least :data:`MIN_CV_BLOCKS`
            blocks; at least :data:`MIN_BLOCK_SAMPLES` samples).

    Returns:
        int ``[n]`` fold of each sample. A single fold (:func:`n_cv_folds` 1) means the residual
        is too short to cross-validate: every fit's CV gain is then undefined.
    """
    segs = list(res.segment_slices())
    if block_s is None:
        f = res.f_dominant_hz
        block_s = 2.0 / f if math.isfinite(f) and f > 0 else 40 * res.dt
        L = max(MIN_BLOCK_SAMPLES, int(round(block_s / res.dt)))
        if sum(max(1, len(idx) // L) for idx in segs) < MIN_CV_BLOCKS:  # a short clip: shorter blocks, not one fold
            L = max(MIN_BLOCK_SAMPLES, max(len(idx) for idx in segs) // MIN_CV_BLOCKS)
    else:
        L = max(MIN_BLOCK_SAMPLES, int(round(block_s / res.dt)))
    out = np.empty(res.n, int)
    b = 0
    for idx in segs:
        nb = max(1, len(idx) // L)
        blk = np.minimum(np.arange(len(idx)) * nb // len(idx), nb - 1)
        out[idx] = (b + blk) % n_folds
        b += nb
    return out


def n_cv_folds(folds: np.ndarray) -> int:
    """Number of distinct folds of :func:`blocked_folds`' labels (below 2: no cross-validation)."""
    return int(len(np.unique(folds)))

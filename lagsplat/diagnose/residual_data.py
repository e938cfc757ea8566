"""The residual as data: the de-blurred state of each segment and the residual generalized force with what explains it.

:func:`lagsplat.diagnose.residual.residual_force` computes a :class:`Residual`;
the candidates of :mod:`lagsplat.diagnose.effects` evaluate their features on
its :class:`SegmentState` and are compared with it through
:meth:`Residual.features` (paper Eq. 7; see "Differentiation" in
:mod:`lagsplat.diagnose.residual`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter1d

from lagsplat import metrics

__all__ = ["SegmentState", "Residual"]


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
        whole: ``slice`` of the padded samples that are the segment's own frames (no padding,
            the edges ``keep`` trims included).
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
    whole: slice


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
            candidates are fitted (see "Smoothing width" in :mod:`lagsplat.diagnose.residual`), or
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

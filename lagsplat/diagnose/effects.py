"""The library of candidate unmodelled effects.

The Lagrangian class of the paper (§3.3) leaves out dry friction, contact,
impacts, non-polynomial stiffness, unlogged inputs and slow changes of the
system (paper §5, "Limitations"). Each candidate below is one such effect
written as a generalized force ``f_eff`` that enters the right-hand side of
the Euler-Lagrange equation (paper Eq. 7) additively::

    M(q) qddot = -dV/dq - C(q) qdot + b(q)^T u + f_eff(q, qdot, t, u).

A candidate acts along one latent direction ``e`` (unit, ``[d]``): with the
scalar coordinate ``s = e^T q``, ``f_eff = e phi(s, sdot, t, u)^T w`` (virtual
work: a force on ``s`` is ``e`` times its magnitude). ``phi`` are the
candidate's *features*, linear in the coefficients ``w``; the few nonlinear
parameters (an end-stop position, a frequency, a delay)
are profiled over a grid (:meth:`Effect.grid`). Features are signed so that a
physical coefficient is non-negative where physics fixes a sign
(:attr:`Effect.positive`).

=================== =================================================== ============================== ==================
name                ``phi`` (``s`` centred on its mean ``s_bar``)        nonlinear parameters           coefficients
=================== =================================================== ============================== ==================
``coulomb``         ``-tanh(sdot / v_s)``, ``v_s`` 0.02 rms speed        -- (``v_s`` set: sharp sign)   ``mu >= 0``
``quadratic_drag``  ``-|sdot| sdot``                                     --                             ``c2 >= 0``
``end_stop``        ``-side relu(side (s - s_stop))``                    ``s_stop``, ``side = +-1``     ``k_stop >= 0``
``cubic_stiffness`` ``-(s - s_bar)^3``                                   --                             ``k3`` (> 0 hardening)
``periodic_force``  ``cos(2 pi f t), sin(2 pi f t)`` (clip time)         ``f``                          ``a, b``
``drift``           ``-(t - t_bar)(s - s_bar), -(t - t_bar) sdot``       --                             ``dk/dt, dc/dt``
``actuation_delay`` ``u(t - tau) - u(t)`` per channel                    ``tau``                        ``gain`` per channel
``missing_dof``     ``exp(-l t') cos(2 pi f t'), exp(-l t') sin(..)`` per ``f``, ``zeta`` (``l = 2 pi f     amplitudes per
                    segment, ``t'`` time since the segment start         zeta``)                        segment
=================== =================================================== ============================== ==================

Where the search is restricted:

* ``cubic_stiffness`` and ``end_stop`` are *in class* (:attr:`Effect.in_class`):
  a convex potential can partly follow them, so they are fitted against the
  model's linearisation and must reach a physical size (:meth:`Effect.practical`);
  a cubic stiffness must also shift the recorded periods with amplitude in its
  own direction (``res.meta["frequency_signature"]``, set by
  :func:`~lagsplat.diagnose.select.select_effect`), which a distorted chart cannot;
* a ``periodic_force`` must drive, off resonance, a motion of at least 1 % of
  the recorded one (rms; :meth:`Effect.practical`): coherent over a whole clip,
  a far smaller one passes the statistical rule (an actuated control of the
  blind suite: 0.34 %, Delta BIC 10.5; the weakest real one there 2.5 %) but
  changes nothing the video shows;
* ``periodic_force`` and ``missing_dof`` are not sought near the model's own
  modes, their harmonics and combination tones, nor near the logged
  inputs' frequencies (:func:`_excluded`), where a residual is a distortion of
  the motion the model has (or an input-gain error), not something it lacks;
* a hidden mode is lightly damped (``zeta <= 0.05``): a residual that dies out
  within a few cycles is a transient, not a degree of freedom.

Features are evaluated on the de-blurred state of the residual
(:class:`~lagsplat.diagnose.residual.SegmentState`), except ``end_stop``, whose
position, stiffness and share of samples in contact are read on the chart's
own, unsmoothed positions: a bounce lasts a few frames, the smoothing pulls
its turning point in, and the first-order de-blurring gives back little of it.
On the cart stand-in of ``tests/test_diagnose.py`` the stop sat 0.08 chart
units too shallow on the smoothed positions; on the de-blurred ones it was
placed right but came out 2.3 times too stiff; on the chart's own positions the
stiffness is within 10 % of the truth.

The energy-consistent torch forms used to refit Stage 2 with a winning effect
are in :mod:`lagsplat.diagnose.terms`.

References: Coulomb friction with a smooth sign, e.g. Olsson et al., "Friction
models and friction compensation", Eur. J. Control 4 (1998); quadratic
(form) drag, Morison-type ``|v| v``; penalty contact, e.g. Hunt & Crossley,
J. Appl. Mech. 42 (1975) without the damping part; hardening / softening
(Duffing) stiffness, Nayfeh & Mook, "Nonlinear Oscillations" (1979), ch. 4.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from lagsplat.diagnose.residual import Residual, SegmentState

__all__ = ["Effect", "EFFECTS", "get_effect", "effect_names", "residual_peaks"]

Feature = Callable[[SegmentState], np.ndarray]


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


def _excluded(res: Residual) -> tuple[tuple[float, float], ...]:
    """``(frequency, relative half-width)`` bands where a periodic force or hidden mode is not sought.

    The model's own modes (``res.meta["model_freqs_hz"]``) and the dominant
    frequency of the encoded motion itself (+-10 %), their harmonics and, with
    several modes, their sum and difference frequencies (+-12 % of the mode
    frequency): a residual there is a misfit or a distortion (a nonlinear chart
    or force) of the motion the model has, not a force or a mode it lacks (and a
    force locked to a harmonic could not be told from one); and the logged
    inputs' strongest frequencies (+-10 %), where an unlogged force cannot be
    told from an input-gain error. The observed frequency counts besides the
    model's linearised ones because a chart distortion puts its harmonics at
    multiples of the motion *as recorded*: on a control clip of the blind suite
    (``cart-none-1``, model mode 0.78 Hz, motion 0.755 Hz) the 2nd harmonic of the
    motion, 1.465 Hz, sat just outside the band around twice the model's mode
    and was taken for a hidden mode.
    """
    base = sorted({f for f in [*res.meta.get("model_freqs_hz", []), res.f_dominant_hz] if math.isfinite(f) and f > 0})
    f_max = 0.25 / res.dt
    # harmonics k f (k >= 2) up to the band edge, each +-0.12 f: a distorted chart or force puts power there
    out = [(f, 0.1) for f in base] + [(k * f, 0.12 / k) for f in base for k in range(2, int(f_max / f) + 2)]
    out += [(g, 0.12 * min(f, h) / g) for i, f in enumerate(base) for h in base[i + 1 :] for g in (f + h, abs(f - h)) if g > 0]  # combination tones
    for j in range(res.n_u):
        out += [(f, 0.1) for f in residual_peaks(res.u[:, j], res.segment, res.dt, 3)]
    return tuple(out)


def _allowed(res: Residual, f: float) -> bool:
    """Whether a periodic force / hidden mode at ``f`` Hz may be sought: inside the searchable band, outside :func:`_excluded`."""
    T = max(len(st.t) for st in res.states) * res.dt
    if not (1.5 / T <= f <= 0.25 / res.dt):
        return False
    return all(abs(f - g) > rel * g for g, rel in _excluded(res) if math.isfinite(g) and g > 0)


def residual_peaks(
    x: np.ndarray, seg: np.ndarray, dt: float, n_peaks: int = 3, f_min: float | None = None, f_max: float | None = None,
    exclude: tuple[tuple[float, float], ...] = (),
) -> list[float]:
    """Frequencies (Hz) of the strongest peaks of a residual's power spectrum.

    The Hann-windowed periodogram of each segment (zero-padded to a common
    grid of ``1 / (4 T_max)`` Hz), summed over segments (incoherently);
    local maxima by :func:`scipy.signal.find_peaks`, strongest first.

    Args:
        x: ``[n]`` residual (one coordinate).
        seg: ``[n]`` segment index of each sample.
        dt: sampling interval, s.
        n_peaks: number of peaks returned (at most).
        f_min, f_max: band searched, Hz (default: 1.5 cycles of the longest segment
            to a quarter of the sampling rate).
        exclude: ``(frequency, relative half-width)`` bands skipped (see :func:`_excluded`).

    Returns:
        Up to ``n_peaks`` frequencies, Hz.
    """
    from scipy.signal import find_peaks

    parts = [x[seg == k] for k in np.unique(seg)]
    parts = [p - p.mean() for p in parts if len(p) >= 8]
    if not parts:
        return []
    L = max(len(p) for p in parts)
    nfft = 1 << int(math.ceil(math.log2(4 * L)))
    f = np.fft.rfftfreq(nfft, dt)
    P = sum(np.abs(np.fft.rfft(p * np.hanning(len(p)), nfft)) ** 2 for p in parts)
    lo = 1.5 / (L * dt) if f_min is None else f_min
    hi = 0.25 / dt if f_max is None else f_max
    band = (f >= lo) & (f <= hi)
    for f_x, rel in exclude:
        if math.isfinite(f_x) and f_x > 0:
            band &= np.abs(f - f_x) > rel * f_x
    if not band.any():
        return []
    Pb = np.where(band, P, 0.0)
    idx, _ = find_peaks(Pb)
    idx = idx[np.argsort(Pb[idx])[::-1]][:n_peaks]
    return [float(f[i]) for i in idx]


@dataclass(frozen=True)
class Effect:
    """One candidate unmodelled effect: its features, parameter grid and reading.

    Attributes:
        name: identifier (also the synthetic label, :mod:`lagsplat.synth.effects`).
        title: a human-readable name.
        kind: ``"dissipative"``, ``"conservative"``, ``"time"`` (explicit time
            dependence), ``"input"`` (acts on the logged actuation) or ``"mode"``
            (a hidden degree of freedom).
        positive: the coefficients must be ``>= 0`` for the effect to be physical.
        n_nonlinear: number of profiled nonlinear parameters (counted by the information criterion).
        signature: the evidence expected in the data if the effect is present.
        in_class: a conservative, position-only force that the model class itself can
            partly represent (a convex potential can bend to follow it): such a
            candidate is fitted against the model's *linearisation* (so that what the
            model has absorbed, or mis-learned, is seen in full) and must pass a
            minimum physical size (:meth:`practical`).
    """

    name: str
    title: str
    kind: str
    positive: bool
    n_nonlinear: int
    signature: str
    in_class: bool = False

    # ------------------------------------------------------------------ interface
    def applicable(self, res: Residual) -> bool:
        """Whether the effect can be tested on this residual (e.g. a delay needs actuation)."""
        return True

    def grid(self, res: Residual, e: np.ndarray, r0: np.ndarray) -> list[dict[str, Any]]:
        """Values of the nonlinear parameters to profile over.

        Args:
            res: the residual.
            e: ``[d]`` unit direction of the effect.
            r0: ``[n]`` the residual along ``e`` after the nuisance (model-class) terms are removed.
        """
        return [{}]

    def refine(self, res: Residual, e: np.ndarray, best: dict[str, Any]) -> list[dict[str, Any]]:
        """A finer grid around the best coarse value (empty: no refinement)."""
        return []

    def feature(self, res: Residual, e: np.ndarray, params: dict[str, Any]) -> tuple[Feature, list[str]]:
        """``(phi, names)``: the feature function on a :class:`SegmentState` (``-> [m,p]``) and its column names."""
        raise NotImplementedError

    def interpret(self, coef: np.ndarray, se: np.ndarray, params: dict[str, Any], res: Residual, e: np.ndarray, scale: dict[str, float]) -> dict[str, Any]:
        """Physical reading of the fitted coefficients (values, standard errors, relative sizes).

        Args:
            coef, se: ``[p]`` coefficients and their standard errors (generalized-force units).
            params: the chosen nonlinear parameters.
            res: the residual.
            e: ``[d]`` direction.
            scale: ``{"k": linear stiffness along e, "c": linear damping along e,
                "s_rms", "s_raw_rms" (the chart's unsmoothed positions), "sdot_rms", "s_bar",
                "t_bar"}`` of the fitted model and data.
        """
        return {}

    def practical(self, interpretation: dict[str, Any], thresholds: dict[str, float]) -> tuple[bool, str]:
        """Whether the fitted effect is large enough to matter physically, and why not.

        In-class candidates have a size rule (:class:`_Cubic`, :class:`_EndStop`), and so
        does the periodic force (:class:`_Periodic`: the motion it drives must reach 1 % of the
        recorded one); the others must merely pass the statistical rule.
        """
        return True, ""

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def coords(st: SegmentState, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(s, sdot)`` ``[m]`` of a segment along ``e``."""
        return st.q @ e, st.qdot @ e


def _ratio(a: float, b: float) -> float:
    return float(a / b) if b not in (0.0,) and math.isfinite(b) else float("nan")


class _Coulomb(Effect):
    #: smooth-sign velocity ``v_s`` as a fraction of the rms speed along ``e``: set, not fitted (see :meth:`grid`)
    V_S_FRACTION = 0.02

    def grid(self, res, e, r0):
        """One value, ``v_s = 0.02`` rms speed: dry friction is sharp, and the residual cannot say otherwise.

        The residual is smoothed over ``sigma`` frames, in which the speed near a
        reversal sweeps a large part of its range, so the residual barely tells
        a sharp sign from a smooth one: on the blind suite's four friction clips
        the BIC over ``v_s`` from 0.01 to 0.4 rms speed moves by 8 or less. Fitted
        anyway, ``v_s`` went where the noise put it (2.3 chart units/s on
        ``cart-coulomb-0``, 0.64 of its rms speed), and the refit with that
        near-viscous term decayed exponentially: envelope error 0.068 against 0.037
        for the model without it; 0.004 with ``v_s`` set here.
        """
        v = float(np.sqrt(np.mean((res.qdot @ e) ** 2)))
        return [{"v_s": self.V_S_FRACTION * v}]

    def feature(self, res, e, params):
        vs = params["v_s"]
        return (lambda st: -np.tanh(self.coords(st, e)[1] / vs)), ["mu"]

    def interpret(self, coef, se, params, res, e, scale):
        mu = float(coef[0])
        return {
            "mu": mu, "mu_se": float(se[0]), "v_s": params["v_s"],
            "mu_over_restoring": _ratio(mu, scale["k"] * scale["s_rms"]),
            "amplitude_loss_per_cycle": _ratio(4 * mu, scale["k"]),
            "text": f"dry friction of level {mu:.3g} +- {se[0]:.2g} ({100 * _ratio(mu, scale['k'] * scale['s_rms']):.1f} % of the "
            f"restoring force at the rms amplitude): a linear envelope losing {_ratio(4 * mu, scale['k']):.3g} (latent units) per cycle",
        }  # fmt: skip


class _Drag(Effect):
    def feature(self, res, e, params):
        def phi(st):
            v = self.coords(st, e)[1]
            return -np.abs(v) * v

        return phi, ["c2"]

    def interpret(self, coef, se, params, res, e, scale):
        c2 = float(coef[0])
        eq = c2 * 8.0 / (3.0 * math.pi) * scale["sdot_rms"] * math.sqrt(2)  # equivalent viscous at the rms speed amplitude
        return {
            "c2": c2, "c2_se": float(se[0]),
            "equivalent_viscous_over_model": _ratio(eq, scale["c"]),
            "text": f"quadratic drag c2 = {c2:.3g} +- {se[0]:.2g}: at the rms speed it equals "
            f"{_ratio(eq, scale['c']):.2f}x the model's viscous damping; the envelope decays hyperbolically",
        }  # fmt: skip


class _EndStop(Effect):
    def grid(self, res, e, r0):
        s = res.q_raw @ e
        out = []
        for side, qs in ((1.0, (0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.96, 0.98)), (-1.0, (0.5, 0.4, 0.3, 0.2, 0.15, 0.1, 0.07, 0.04, 0.02))):
            for a in np.quantile(s, qs):
                out.append({"side": side, "s_stop": float(a)})
        return out

    def refine(self, res, e, best):
        s = res.q_raw @ e
        step = 0.01 * float(np.ptp(s))
        return [{"side": best["side"], "s_stop": float(best["s_stop"] + k * step)} for k in (-4, -3, -2, -1, 1, 2, 3, 4)]

    def feature(self, res, e, params):
        side, a = params["side"], params["s_stop"]
        return (lambda st: -side * _relu(side * (st.q_raw @ e - a))), ["k_stop"]

    def practical(self, interpretation, thresholds):
        ratio = interpretation.get("stiffness_ratio", float("nan"))
        lo = thresholds.get("min_stop_stiffness_ratio", 2.0)
        if not (ratio >= lo):
            return False, f"stop stiffness {ratio:.2g}x the spring's, below {lo:g}x: a gentle asymmetry of the spring, not a stop"
        return True, ""

    def interpret(self, coef, se, params, res, e, scale):
        k = float(coef[0])
        s = res.q_raw @ e
        frac = float(np.mean(params["side"] * (s - params["s_stop"]) > 0))
        return {
            "k_stop": k, "k_stop_se": float(se[0]), "s_stop": params["s_stop"], "side": params["side"],
            "stiffness_ratio": _ratio(k, scale["k"]), "fraction_in_contact": frac,
            "text": f"one-sided stop at s = {params['s_stop']:.3g} ({'upper' if params['side'] > 0 else 'lower'} side, "
            f"{100 * frac:.0f} % of samples in contact), stiffness {k:.3g} +- {se[0]:.2g} = {_ratio(k, scale['k']):.2g}x the model's",
        }  # fmt: skip


class _Cubic(Effect):
    def feature(self, res, e, params):
        s_bar = float(np.mean(res.q @ e))
        return (lambda st: -((self.coords(st, e)[0] - s_bar) ** 3)), ["k3"]

    def practical(self, interpretation, thresholds):
        pred = interpretation.get("relative_frequency_shift_at_amplitude", float("nan"))
        lo = thresholds.get("min_cubic_shift", 0.03)
        if not (abs(pred) >= lo):
            return False, f"frequency shift {100 * abs(pred):.1f} % at the largest amplitude, below {100 * lo:g} %"
        # A Duffing term shifts the period with amplitude; a chart that stretches large excursions
        # (q a nonlinear function of the physical coordinate) does not: zero-crossing periods are
        # chart-invariant. Accept only a shift the recording shows, with the sign of k3.
        meas = interpretation.get("measured_frequency_shift")
        if meas is not None and math.isfinite(meas) and not (meas * pred > 0 and abs(meas) >= 0.5 * lo):
            return False, (
                f"the recorded periods shift by {100 * meas:+.1f} % at the largest amplitude (frequency vs amplitude^2, "
                f"z = {interpretation.get('measured_frequency_z', float('nan')):.1f}) where this k3 predicts {100 * pred:+.1f} %: "
                "the anharmonic waveform in q comes from the chart, not from a stiffness"
            )
        return True, ""

    def interpret(self, coef, se, params, res, e, scale):
        k3 = float(coef[0])
        s = res.q @ e
        x = s - s.mean()
        A = float(np.quantile(np.abs(x), 0.99))
        # the linear stiffness without the part of the cubic that a straight-line fit absorbs
        k1 = scale["k"] - k3 * float(np.mean(x**4) / max(np.mean(x**2), 1e-300))
        shift = 3.0 * k3 * A * A / (8.0 * k1) if k1 > 0 else float("nan")
        fsig = res.meta.get("frequency_signature") or {}  # select_effect's evidence (chart-invariant periods)
        meas = fsig.get("relative_shift_at_max_amplitude") if fsig.get("n_periods", 0) >= 6 else None
        return {
            "k3": k3, "k3_se": float(se[0]), "kind": "hardening" if k3 > 0 else "softening",
            "relative_frequency_shift_at_amplitude": shift, "amplitude": A, "s_bar": float(s.mean()), "k_linear": k1,
            "measured_frequency_shift": None if meas is None else float(meas),
            "measured_frequency_z": None if meas is None else float(fsig["z_amp2"]),
            "text": f"{'hardening' if k3 > 0 else 'softening'} cubic stiffness k3 = {k3:.3g} +- {se[0]:.2g}: "
            f"frequency {'+' if shift >= 0 else ''}{100 * shift:.1f} % at amplitude {A:.3g} (Duffing, 3 k3 A^2 / 8 k); "
            "in the latent coordinate, where a chart that stretches or compresses large excursions looks the same",
        }  # fmt: skip


class _Periodic(Effect):
    def grid(self, res, e, r0):
        peaks = residual_peaks(r0, res.segment, res.dt, 3, exclude=_excluded(res))
        T = max(len(st.t) for st in res.states) * res.dt
        out = []
        for f in peaks:
            for k in np.linspace(-1.0, 1.0, 11):
                fk = f + k / T
                if _allowed(res, fk):
                    out.append({"f_hz": float(fk)})
        return out

    def refine(self, res, e, best):
        # the phase is locked over the whole clip: resolve f to ~0.01 / (time span)
        span = float(np.ptp(res.t)) + res.dt
        T = max(len(st.t) for st in res.states) * res.dt
        return [{"f_hz": float(best["f_hz"] + k)} for k in np.arange(-0.2 / T, 0.2 / T + 1e-12, 0.01 / span) if _allowed(res, best["f_hz"] + k)]

    def feature(self, res, e, params):
        w = 2 * math.pi * params["f_hz"]
        return (lambda st: np.stack([np.cos(w * st.t), np.sin(w * st.t)], 1)), ["a_cos", "b_sin"]

    def practical(self, interpretation, thresholds):
        rel = interpretation.get("driven_over_motion", float("nan"))
        lo = thresholds.get("min_periodic_response", 0.01)
        if not (rel >= lo):
            return False, (f"the motion it drives off resonance is {100 * rel:.2g} % of the recorded motion (rms), below "
                           f"{100 * lo:g} %: a force too small to change what the video shows")  # fmt: skip
        return True, ""

    def interpret(self, coef, se, params, res, e, scale):
        amp = float(np.hypot(coef[0], coef[1]))
        amp_se = float(np.sqrt((coef[0] * se[0]) ** 2 + (coef[1] * se[1]) ** 2) / max(amp, 1e-300))
        r = _ratio(params["f_hz"], res.f_dominant_hz)
        return {
            "f_hz": params["f_hz"], "amplitude": amp, "amplitude_se": amp_se, "phase": float(math.atan2(-coef[1], coef[0])),
            "f_over_model": r,
            "amplitude_over_restoring": _ratio(amp, scale["k"] * scale["s_rms"]),
            # linear response of the fitted spring off resonance (the model's own band is excluded):
            # amplitude / (k |1 - r^2|), as an rms, over the rms of the recorded (unsmoothed) motion along e
            "driven_over_motion": _ratio(amp, scale["k"] * abs(1.0 - r * r) * math.sqrt(2.0) * scale["s_raw_rms"]),
            "text": f"an unlogged periodic force at {params['f_hz']:.3g} Hz ({r:.2f}x the "
            f"oscillation), amplitude {amp:.3g} +- {amp_se:.2g}, phase-locked over the clip",
        }  # fmt: skip


class _Drift(Effect):
    def feature(self, res, e, params):
        s_bar = float(np.mean(res.q @ e))
        t_bar = float(np.mean(res.t))

        def phi(st):
            s, v = self.coords(st, e)
            dt = st.t - t_bar
            return np.stack([-dt * (s - s_bar), -dt * v], 1)

        return phi, ["dk_dt", "dc_dt"]

    def interpret(self, coef, se, params, res, e, scale):
        span = float(np.ptp(res.t))
        rk, rc = _ratio(coef[0] * span, scale["k"]), _ratio(coef[1] * span, scale["c"])
        zk, zc = abs(coef[0]) / max(se[0], 1e-300), abs(coef[1]) / max(se[1], 1e-300)
        which = "stiffness" if zk >= zc else "damping"
        return {
            "dk_dt": float(coef[0]), "dk_dt_se": float(se[0]), "dc_dt": float(coef[1]), "dc_dt_se": float(se[1]),
            "stiffness_change_over_clip": rk, "damping_change_over_clip": rc, "dominant": which,
            "t_bar": float(np.mean(res.t)), "s_bar": float(np.mean(res.q @ e)), "k_model": scale["k"], "c_model": scale["c"],
            "text": f"slow drift, mainly of the {which}: over the {span:.0f} s recorded the stiffness changes by "
            f"{100 * rk:+.1f} % (z = {zk:.1f}) and the damping by {100 * rc:+.0f} % (z = {zc:.1f})",
        }  # fmt: skip


class _Delay(Effect):
    def applicable(self, res):
        return res.n_u > 0

    def grid(self, res, e, r0):
        n = int(round(0.5 / res.dt))
        return [{"tau_s": float(k * res.dt / 2)} for k in range(1, 2 * n + 1)]

    def feature(self, res, e, params):
        tau = params["tau_s"]
        return (lambda st: st.u_at(st.t - tau) - st.u_at(st.t)), [f"gain_u{j + 1}" for j in range(res.n_u)]

    def interpret(self, coef, se, params, res, e, scale):
        return {
            "tau_s": params["tau_s"], "gain": [float(c) for c in coef], "gain_se": [float(s) for s in se],
            "text": f"the logged input acts {params['tau_s'] * 1000:.0f} ms late (delayed-input gain "
            + ", ".join(f"{c:.3g} +- {s:.2g}" for c, s in zip(coef, se)) + ")",
        }  # fmt: skip


class _MissingDof(Effect):
    def grid(self, res, e, r0):
        peaks = residual_peaks(r0, res.segment, res.dt, 3, exclude=_excluded(res))
        T = max(len(st.t) for st in res.states) * res.dt
        out = []
        for f in peaks:
            for k in np.linspace(-1.0, 1.0, 9):
                fk = f + k / T
                if not _allowed(res, fk):
                    continue
                for z in (0.0, 0.0025, 0.005, 0.01, 0.02, 0.04):
                    out.append({"f_hz": float(fk), "zeta": z})
        return out

    def refine(self, res, e, best):
        T = max(len(st.t) for st in res.states) * res.dt
        z0 = best["zeta"]
        # a lightly damped mode (zeta <= 0.05): a residual that dies out within a few cycles is a transient, not a mode
        zs = sorted({min(0.05, max(0.0, z0 * f)) for f in (0.6, 0.8, 1.0, 1.25, 1.5)} | {max(0.0, z0 - 0.0025), min(0.05, z0 + 0.0025)})
        return [{"f_hz": float(best["f_hz"] + k), "zeta": float(z)} for k in np.linspace(-0.25 / T, 0.25 / T, 11) for z in zs if _allowed(res, best["f_hz"] + k)]

    def feature(self, res, e, params):
        w = 2 * math.pi * params["f_hz"]
        lam = params["zeta"] * w
        n_seg = res.n_segments

        def phi(st):
            tt = st.t - st.t[st.keep.start]
            env = np.exp(-lam * tt)
            out = np.zeros((len(st.t), 2 * n_seg))
            out[:, 2 * st.index] = env * np.cos(w * tt)
            out[:, 2 * st.index + 1] = env * np.sin(w * tt)
            return out

        return phi, [f"seg{k}_{c}" for k in range(n_seg) for c in ("cos", "sin")]

    def interpret(self, coef, se, params, res, e, scale):
        a = np.hypot(coef[0::2], coef[1::2])
        return {
            "f_hz": params["f_hz"], "zeta": params["zeta"], "segment_amplitudes": a.tolist(),
            "f_over_model": _ratio(params["f_hz"], res.f_dominant_hz),
            "text": f"a hidden mode at {params['f_hz']:.3g} Hz ({_ratio(params['f_hz'], res.f_dominant_hz):.2f}x the oscillation), "
            f"damping ratio ~{params['zeta']:.3g}, with its own amplitude and phase in each segment: a degree of freedom the "
            "latent chart does not carry (remedy: one more latent dimension)",
        }  # fmt: skip


#: The candidate library, in a fixed order.
EFFECTS: tuple[Effect, ...] = (
    _Coulomb("coulomb", "dry (Coulomb) friction", "dissipative", True, 0,
             "linear (not exponential) envelope decay; residual a square wave in phase with -sign(qdot)"),
    _Drag("quadratic_drag", "quadratic drag", "dissipative", True, 0,
          "hyperbolic envelope decay (faster at large amplitude); residual ~ -|qdot| qdot"),
    _EndStop("end_stop", "one-sided end stop / contact", "conservative", True, 2,
             "residual spikes at one turning point only; amplitude clipped on one side; frequency rises with amplitude",
             in_class=True),
    _Cubic("cubic_stiffness", "hardening / softening stiffness", "conservative", False, 0,
           "frequency depends on amplitude (rises: hardening, falls: softening); residual odd in q, with a 3rd harmonic",
           in_class=True),
    _Periodic("periodic_force", "unlogged periodic force", "time", False, 1,
              "residual spectrum peak at a frequency the model lacks, constant amplitude, phase-locked over the clip"),
    _Drift("drift", "slow drift of stiffness or damping", "time", False, 0,
           "frequency or decay rate changing with time, independently of amplitude"),
    _Delay("actuation_delay", "actuation delay", "input", False, 1,
           "residual correlated with the input's rate of change; best lag > 0"),
    _MissingDof("missing_dof", "missing degree of freedom", "mode", False, 2,
                "residual spectrum peak the model lacks, decaying, with a different phase in each recording"),
)  # fmt: skip


def effect_names() -> list[str]:
    """Names of the candidates, in library order."""
    return [e.name for e in EFFECTS]


def get_effect(name: str) -> Effect:
    """The candidate called ``name``.

    Raises:
        KeyError: naming the known candidates if ``name`` is unknown.
    """
    for e in EFFECTS:
        if e.name == name:
            return e
    raise KeyError(f"unknown effect {name!r}; known: {effect_names()}")

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
are profiled over a grid (:meth:`~lagsplat.diagnose.effect_base.Effect.grid`). Features are signed so that a
physical coefficient is non-negative where physics fixes a sign
(:attr:`~lagsplat.diagnose.effect_base.Effect.positive`).

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

* ``cubic_stiffness`` and ``end_stop`` are *in class* (:attr:`~lagsplat.diagnose.effect_base.Effect.in_class`):
  a convex potential can partly follow them, so they are fitted against the
  model's linearisation and must reach a physical size (:meth:`~lagsplat.diagnose.effect_base.Effect.practical`);
  a cubic stiffness must also shift the recorded periods with amplitude in its
  own direction (``res.meta["frequency_signature"]``, set by
  :func:`~lagsplat.diagnose.select.select_effect`), which a distorted chart cannot;
* a ``periodic_force`` must drive, off resonance, a motion of at least 1 % of
  the recorded one (rms; :meth:`~lagsplat.diagnose.effect_base.Effect.practical`): coherent over a whole clip,
  a far smaller one passes the statistical rule (as on an actuated control of the
  blind suite, below the weakest real force there; ``docs/experiments/diagnosis_history.md``) but
  changes nothing the video shows;
* ``periodic_force`` and ``missing_dof`` are not sought near the model's own
  modes, their harmonics and combination tones, nor near the logged
  inputs' frequencies (:func:`~lagsplat.diagnose.spectrum.excluded_bands`), where a residual is a distortion of
  the motion the model has (or an input-gain error), not something it lacks;
* a hidden mode is lightly damped (``zeta <= 0.05``): a residual that dies out
  within a few cycles is a transient, not a degree of freedom.

Features are evaluated on the de-blurred state of the residual
(:class:`~lagsplat.diagnose.residual_data.SegmentState`), except ``end_stop``, whose
position, stiffness and share of samples in contact are read on the chart's
own, unsmoothed positions: a bounce lasts a few frames, the smoothing pulls
its turning point in, and the first-order de-blurring gives back little of it.
On the cart stand-in of ``tests/test_diagnose.py`` the smoothed positions place
the stop too shallow and the de-blurred ones make it too stiff; the chart's own
positions give its position and stiffness (the measurement:
``docs/experiments/code_comment_history.md``).

The energy-consistent torch forms used to refit Stage 2 with a winning effect
are in :mod:`lagsplat.diagnose.terms`.

References: Coulomb friction with a smooth sign, e.g. Olsson et al., "Friction
models and friction compensation", Eur. J. Control 4 (1998); quadratic
(form) drag, Morison-type ``|v| v``; penalty contact, e.g. Hunt & Crossley,
J. Appl. Mech. 42 (1975) without the damping part; hardening / softening
(Duffing) stiffness, Nayfeh & Mook, "Nonlinear Oscillations" (1979), ch. 4.

The interface is :class:`~lagsplat.diagnose.effect_base.Effect`; the
candidates are implemented in :mod:`lagsplat.diagnose.effects_state` (friction,
drag, end stop, cubic stiffness) and :mod:`lagsplat.diagnose.effects_time`
(periodic force, drift, delay, hidden mode).
"""

from __future__ import annotations

from lagsplat.diagnose.effect_base import Effect
from lagsplat.diagnose.effects_state import (
    CoulombEffect,
    CubicStiffnessEffect,
    EndStopEffect,
    QuadraticDragEffect,
)
from lagsplat.diagnose.effects_time import (
    ActuationDelayEffect,
    DriftEffect,
    MissingDofEffect,
    PeriodicForceEffect,
)

__all__ = ["EFFECTS", "get_effect", "effect_names"]


#: The candidate library, in a fixed order.
EFFECTS: tuple[Effect, ...] = (
    CoulombEffect("coulomb", "dry (Coulomb) friction", "dissipative", True, 0,
                  "linear (not exponential) envelope decay; residual a square wave in phase with -sign(qdot)"),
    QuadraticDragEffect("quadratic_drag", "quadratic drag", "dissipative", True, 0,
                        "hyperbolic envelope decay (faster at large amplitude); residual ~ -|qdot| qdot"),
    EndStopEffect("end_stop", "one-sided end stop / contact", "conservative", True, 2,
                  "residual spikes at one turning point only; amplitude clipped on one side; frequency rises with amplitude",
                  in_class=True),
    CubicStiffnessEffect("cubic_stiffness", "hardening / softening stiffness", "conservative", False, 0,
                         "frequency depends on amplitude (rises: hardening, falls: softening); residual odd in q, with a 3rd harmonic",
                         in_class=True),
    PeriodicForceEffect("periodic_force", "unlogged periodic force", "time", False, 1,
                        "residual spectrum peak at a frequency the model lacks, constant amplitude, phase-locked over the clip"),
    DriftEffect("drift", "slow drift of stiffness or damping", "time", False, 0,
                "frequency or decay rate changing with time, independently of amplitude", also_in_class=True),
    ActuationDelayEffect("actuation_delay", "actuation delay", "input", False, 1,
                         "residual correlated with the input's rate of change; best lag > 0"),
    MissingDofEffect("missing_dof", "missing degree of freedom", "mode", False, 2,
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

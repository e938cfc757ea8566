"""Stage-2 settings (``conf/config.yaml``, group ``stage2``; paper §3.3, Eq. 8, App. C)."""

from __future__ import annotations

import math

from dataclasses import dataclass
from typing import Any, Literal, Mapping

from lagsplat.models.inertia import DecoderInertia
from lagsplat.models.lagrangian import Lagrangian
from lagsplat.train.config import dataclass_from_mapping

__all__ = ["PAPER_FIT", "Stage2Config", "Mass", "Potential"]

Mass = Literal["auto", "scalar", "constant", "learned", "decoder"]
"""Inertia models of Stage 2 (``stage2.mass``; :class:`~lagsplat.models.lagrangian.Lagrangian`);
``"auto"`` is resolved per chart by :meth:`Stage2Config.effective_mass`."""

Potential = Literal["convex", "invex"]
"""Potentials of Stage 2 (``stage2.potential``): ICNN, or ICNN o i-ResNet."""


PAPER_FIT: dict[str, Any] = {"mass": "scalar", "rollout_steps": 1, "potential_kinks": 0.0}
"""The paper's Stage-2 fit of a d = 1 chart (§3.3, Eq. 8): ``Stage2Config(**PAPER_FIT, ...)``."""


@dataclass
class Stage2Config:
    """Stage-2 settings (``conf/config.yaml``, group ``stage2``).

    The defaults are those of a new clip (``conf/config.yaml``): the inertia chosen per chart
    (``mass="auto"``) and, on d = 1 charts, four chained steps per window and kinks spread over the range. The paper's fit (Eq. 8) is
    ``mass="scalar"`` for d = 1, ``rollout_steps=1``, ``potential_kinks=0``.

    Attributes:
        mass: ``"scalar"``, ``"constant"``, ``"learned"`` or ``"decoder"`` inertia
            (see :class:`Lagrangian`; ``"decoder"`` needs the Stage-1 decoder), or ``"auto"``:
            ``"learned"``, except on a d = 1 chart with a logged input, where it is ``"scalar"``
            (:meth:`effective_mass`). There the learned ``M(q)`` trades off against the actuation
            map (on the blind suite's actuated pendulum and cart with nothing missing it read the held-out
            gap, and the pendulum's frequency, worse than the scalar inertia;
            ``docs/experiments/code_comment_history.md``).
        potential: ``"convex"`` (ICNN) or ``"invex"`` (ICNN o i-ResNet).
        c0: dissipation floor (App. C: 1).
        dissipation_init: initial learned dissipation (0.2 I).
        hidden: MLP / ICNN widths.
        eps_V: quadratic floor of the potential.
        learn_rest: train the rest state.
        zeta_floor: damping ratio the floor alone gives at initialisation.
        stride: frames per training step ``k`` (reference: 2).
        max_step_phase: largest phase ``omega h`` (rad) of the training step ``h = k dt`` at the training
            frames' observed frequency. Above it the step is integrated as ``k`` Verlet steps of one frame
            and scored against one-frame central-difference velocities, so that the model fitted is the
            frame-rate map every rollout runs (a Verlet step's frequency error grows as ``(omega h)^2 / 24``:
            an exact oscillator filmed at few frames per period is identified low with stride-2 steps, close
            with the frame-interval steps; ``docs/experiments/code_comment_history.md``). 0: always; a large value:
            never (the reference code).
        sigma: Gaussian smoothing of the encoded trajectory, frames (reference: 1).
        w_q, w_v: weights of position and velocity terms of Eq. 8.
        lr, epochs, batch, windows_per_epoch, grad_clip: optimisation.
        lr_potential_input: learning-rate factor of the potential ICNN's input layers (the affine maps of
            ``q`` into each hidden layer, :class:`~lagsplat.models.icnn.ICNN`). A sharp feature of ``V``
            (an end stop's kink) needs input weights many times the initial ones, which Adam reaches
            at about ``lr`` per step. 10 (with ``select_from = 1``) identifies an end stop from its exact
            trajectory better than the default, but on the realistic suite's encoded charts it fits their
            noise and worsens the held-out frequency of plain oscillators
            (``docs/experiments/code_comment_history.md``), so the default stays 1.
        w_actuation_linear: weight of a prior toward a linear actuation map (an actuated model, paper
            Eq. 6): ``w |grad_q sum_j g_j(q)|^2`` at the windows' states is added to the loss
            (:meth:`~lagsplat.models.icnn.ConcaveMap.nonlinearity`). Without it, where the
            pressures never vanish in training, the concave map takes over the restoring force
            (a pressure-proportional stiffness) and the unloaded model is too soft, as on the
            simulated two-segment robot, where 1 keeps the restoring force in ``V`` and brings the
            free frequency at the published budget (500 x 3000 windows) closer to the simulator's
            (``docs/experiments/code_comment_history.md``). 0: the free concave map. No effect without actuation.
        rollout_steps: Verlet steps per training window: 1 is Eq. 8's one-step fit; ``K > 1`` chains the
            step ``K`` times from the window's state and scores every step (:mod:`~lagsplat.train.shooting`),
            so one frame's chart noise is outvoted by the ``K`` frames after it. Used for d = 1 charts
            only: with the learned inertia on a double pendulum (d = 2) four steps read the held-out
            frequency worse than one (``docs/experiments/code_comment_history.md``), so d > 1 charts
            take one step (Eq. 8).
        potential_kinks: sharpness ``s`` of the potential ICNN's kinks, spread over the training range
            (:meth:`~lagsplat.models.icnn.ICNN.spread_kinks`); 0 keeps the default initialisation (every
            kink at the origin), which smears an end stop's wall over the whole range. Used for d = 1
            charts only (in d > 1 they would need directions; random ones did not help a double
            pendulum), so there the kinks stay at the origin; and only on clips without a logged input
            (``n_u = 0``): where an input drives the motion, a potential with sharp kinks over the
            range fits the input's force as a function of ``q`` and the free rollouts fail (as on the
            blind suite's actuated pendulum with nothing missing; ``docs/experiments/code_comment_history.md``).
        potential_kinks_alternatives: further starts of the fit, one per kink sharpness listed (e.g.
            ``[0]``: also every kink at the origin), wherever ``potential_kinks`` is used; each start is
            trained with the same seed and windows, and the one whose selection rollouts score lowest is
            kept (the model selection of paper §3.3, over the starts as over the epochs). A refit
            (``augment``) trains one start. Empty (default): one start. ``[0]`` helps where the spread
            kinks make the fitted frequency depend on the amplitude and hurts on drifts and end stops,
            where the start that follows the training frames best extrapolates worse (measured on the
            realistic and blind suites; ``docs/experiments/diagnosis_history.md``), so the default is one start.
        select_every: epochs between model-selection rollouts.
        select_from: fraction of the epochs after which a model can be selected: 0 (default) selects over
            the whole run on rollout error (paper §3.3), 1 keeps the last epoch's model (the reference
            implementation's checkpoint), the best earlier one only if the last rollout is not finite.
        select_windows, select_periods: rollouts used for selection.
    """

    mass: Mass = "auto"
    potential: Potential = "convex"
    c0: float = 1.0
    dissipation_init: float = 0.2
    hidden: tuple[int, ...] = (64, 64)
    eps_V: float = 0.01
    learn_rest: bool = True
    zeta_floor: float = 0.01
    stride: int = 2
    max_step_phase: float = 0.5
    sigma: float = 1.0
    w_q: float = 0.1
    w_v: float = 0.1
    lr: float = 1e-3
    lr_potential_input: float = 1.0
    w_actuation_linear: float = 1.0
    rollout_steps: int = 4
    potential_kinks: float = 30.0
    potential_kinks_alternatives: tuple[float, ...] = ()
    epochs: int = 300
    batch: int = 32
    windows_per_epoch: int = 1000
    grad_clip: float = 100.0
    select_every: int = 5
    select_from: float = 0.0
    select_windows: int = 16
    select_periods: float = 4.0

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any]) -> "Stage2Config":
        """Build from a (Hydra) mapping; unknown keys raise ``KeyError``."""
        return dataclass_from_mapping(cls, m, "stage2")

    def effective_mass(self, d: int, n_u: int = 0) -> str:
        """The inertia model built for a chart of dimension ``d`` with ``n_u`` logged input channels:
        ``mass`` itself, or for ``"auto"`` ``"scalar"`` where ``d == 1`` and ``n_u > 0``, else ``"learned"``.
        It depends on ``(d, n_u)`` only, so a saved model rebuilds the same (:func:`load_stage2`)."""
        if self.mass != "auto":
            return self.mass
        return "scalar" if d == 1 and n_u > 0 else "learned"

    def substeps(self, f_hz: float, dt: float) -> int:
        """Verlet steps per training step of ``stride`` frames at an observed frequency ``f_hz`` (Hz) and frame
        interval ``dt`` (s): ``stride`` where ``2 pi f_hz stride dt > max_step_phase``, else 1 (also for a
        frequency that could not be read, NaN; see ``max_step_phase``)."""
        return int(self.stride) if 2 * math.pi * f_hz * self.stride * dt > self.max_step_phase else 1

    def effective_rollout_steps(self, d: int) -> int:
        """Verlet steps per training window on a chart of dimension ``d``: ``rollout_steps`` for ``d == 1``,
        else 1 (Eq. 8's one-step fit; see ``rollout_steps``)."""
        return int(self.rollout_steps) if d == 1 else 1

    def effective_kinks(self, d: int, n_u: int = 0) -> float:
        """Sharpness of the potential's spread kinks on a chart of dimension ``d`` with ``n_u`` logged input
        channels: ``potential_kinks`` for ``d == 1`` without an input, else 0 (kinks at the origin; see
        ``potential_kinks``)."""
        return float(self.potential_kinks) if d == 1 and n_u == 0 else 0.0

    def build(self, d: int, n_u: int = 0, inertia: DecoderInertia | None = None) -> Lagrangian:
        """The (untrained) :class:`Lagrangian` these settings describe.

        Args:
            d: latent dimension.
            n_u: actuation channels the model reads (its inertia follows :meth:`effective_mass`).
            inertia: the frozen decoder inertia (``mass="decoder"`` only).
        """
        return Lagrangian(
            d, self.effective_mass(d, n_u), self.c0, self.dissipation_init, tuple(self.hidden), self.eps_V, self.learn_rest,
            potential=self.potential, n_u=n_u, inertia=inertia,
        )  # fmt: skip

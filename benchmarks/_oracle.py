"""The true law of a realistic-suite clip, written in the clip's identified chart: what a perfect model scores and names.

What the clip's own ground-truth law scores on the same chart with the same
protocol is what a model with no gap at all scores: the chart's noise turns
into rollout error for any model, and more so for a stiff or switching one (an
end stop turns the same noise into larger timing errors than a linear spring).
A refit is not expected to score much below it (a little below happens where
the noise favours a slightly different model). :func:`true_law_gap` measures it. The law is
:func:`lagsplat.synth.effects.true_acceleration` in the library's coordinate
``x``; the chart's coordinate is ``q = phi(x)``, with ``phi`` the least-squares
polynomial (cubic) of the encoded ``q`` on the true ``x`` over every frame (the
chart of a pendulum bends, one of a cart does not), so in the chart

    qdot = phi'(x) xdot,   qddot = phi'(x) a(t, x, xdot) + phi''(x) xdot^2.

The same law without the clip's effect (its *control* law) is a perfect model
of the control class: the diagnosis's selection run with it as the model
(:func:`true_control_diagnosis`) sees a residual made of the effect and the
chart's noise only, so what it names is the most the diagnosis can name on
that chart and those frames, whatever Stage 2 learns.

1-DOF clips only (the missing degree of freedom has no 1-DOF law; the double
pendulum no effect law). Used by ``benchmarks/realistic.py --true-law``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from lagsplat.synth.effects import true_acceleration
from lagsplat.synth.realistic.motion import coordinate_scale

__all__ = ["TrueLawInChart", "law_in_chart", "true_law_gap", "true_control_diagnosis", "CHART_MAP_DEGREE"]

CHART_MAP_DEGREE = 3
"""Degree of the polynomial ``q = phi(x)`` from the true coordinate to the chart's."""


class TrueLawInChart(nn.Module):
    """``qddot`` of a clip's true law in chart coordinates (module docstring); the ``acceleration`` interface of Stage 2.

    Args:
        truth: the clip's truth record (``truth_json`` of its ``.truth.npz``).
        coef: ``phi``'s coefficients, highest power first (``numpy.polyfit``), chart units per library unit.
        T_clip: the simulated take's length, s (the drift's time scale).
        time_channel: whether the last actuation channel carries the clip time (periodic force, drift, a logged
            input: the law computes the input from its own record at that time).

    Raises:
        ValueError: for ``missing_dof`` (:func:`~lagsplat.synth.effects.true_acceleration`).
    """

    d = 1

    def __init__(self, truth: dict[str, Any], coef: np.ndarray, T_clip: float, time_channel: bool) -> None:
        super().__init__()
        self.truth = truth
        self.law = true_acceleration(truth, T_clip)
        self.phi = np.poly1d(np.asarray(coef, np.float64))
        self.dphi, self.ddphi = self.phi.deriv(1), self.phi.deriv(2)
        self.time_channel = time_channel

    def _x_of(self, q: np.ndarray) -> np.ndarray:
        """``phi^-1(q)`` by Newton's method from the linear part (``phi`` is monotone over the range of motion)."""
        x = (q - self.phi.coeffs[-1]) / self.dphi(0.0)
        for _ in range(30):
            x = x - (self.phi(x) - q) / self.dphi(x)
        return x

    def acceleration(self, q: Tensor, qdot: Tensor, f_ext: Tensor | None = None, u: Tensor | None = None) -> Tensor:
        """``qddot [B,1]`` at ``q, qdot [B,1]``; ``u [B,n_u]`` carries the time (s) in its last column when ``time_channel``."""
        qq = q.detach().double().numpy()[:, 0]
        x = self._x_of(qq)
        xd = qdot.detach().double().numpy()[:, 0] / self.dphi(x)
        t = u.detach().double().numpy()[:, -1] if self.time_channel and u is not None else 0.0
        a = self.dphi(x) * self.law(t, x, xd) + self.ddphi(x) * xd * xd
        if f_ext is not None:
            a = a + f_ext.detach().double().numpy()[:, 0]
        return torch.as_tensor(a[:, None], dtype=q.dtype)

    def modal_analysis(self, q: Tensor | None = None) -> dict[str, np.ndarray]:
        """The law's nominal mode (``f0``, ``zeta``), for the evaluation record."""
        return {"f_hz": np.array([float(self.truth["f0_hz"])]), "zeta": np.array([float(self.truth["zeta"])])}


def law_in_chart(chart: Any, truth_npz: str | Path, system: str, control: bool = False) -> tuple[TrueLawInChart, bool, float]:
    """The clip's ground-truth law written in the run's chart (module docstring); with ``control``, its *control* law:
    the same system without its effect (the truth with ``effect = "none"``).

    Args:
        chart: the run's :class:`~lagsplat.chart.Chart` (d = 1).
        truth_npz: the clip's ``.truth.npz`` (``q`` in the clip's units, ``truth_json``).
        system: the suite's system name (``pendulum``, ``spring_cart``, ``torsion_disk``; the units of ``q``).
        control: the law without the clip's effect.

    Returns:
        ``(model, time_channel, chart_map_rms)``: the law, whether it reads the clip time from a last input channel
        (:func:`lagsplat.diagnose.terms.with_time_channel`), and the rms of the encoded ``q`` about ``phi(x)``
        (chart units; how well the cubic maps the truth to the chart).

    Raises:
        ValueError: if the chart is not one-dimensional, its frames are not the truth's, the clip has no 1-DOF law,
            or ``control`` is asked of an actuated clip (its control law would read the input through a time channel
            that the residual regression would also see).
    """
    if chart.d != 1:
        raise ValueError(f"{truth_npz}: the true law is written in a 1-D chart, this one has d = {chart.d}")
    z = np.load(truth_npz)
    truth = json.loads(str(z["truth_json"]))
    x = z["q"][:, 0] / coordinate_scale(system, truth)
    q = np.asarray(chart.q, np.float64)[:, 0]
    if len(x) != len(q):
        raise ValueError(f"{truth_npz}: {len(x)} true frames, the chart has {len(q)}")
    if control and truth.get("actuated"):
        raise ValueError(f"{truth_npz}: no control law for an actuated clip")
    coef = np.polyfit(x, q, CHART_MAP_DEGREE)
    if control:
        truth = {**truth, "effect": "none", "effect_params": {}}
    time_channel = truth["effect"] in ("periodic_force", "drift") or bool(truth.get("actuated"))  # the law reads the clip time
    T_clip = float(truth["n_episodes"]) * float(truth["duration_s"])
    rms = float(np.sqrt(np.mean((q - np.polyval(coef, x)) ** 2)))
    return TrueLawInChart(truth, coef, T_clip, time_channel), time_channel, rms


def true_law_gap(chart: Any, truth_npz: str | Path, system: str, eval_cfg: Any | None = None, floor_draws: int = 8) -> dict[str, Any]:
    """Held-out gap of the clip's true law in its chart, by :func:`lagsplat.diagnose.gap.held_out_gap`.

    Args:
        chart, truth_npz, system: as for :func:`law_in_chart`.
        eval_cfg: the evaluation settings (default :class:`lagsplat.evaluate.EvalConfig`).
        floor_draws: Monte-Carlo draws of the chart-noise floor.

    Returns:
        ``{"eps_q", "eps_q_floor", "chart_map_rms"}``: the law's held-out ``eps_q``, its noise floor, and the
        rms of the encoded ``q`` about ``phi(x)`` (:func:`law_in_chart`).

    Raises:
        ValueError: as :func:`law_in_chart`.
    """
    from lagsplat.diagnose.gap import held_out_gap
    from lagsplat.diagnose.terms import with_time_channel

    model, time_channel, rms = law_in_chart(chart, truth_npz, system)
    gap = held_out_gap(with_time_channel(chart) if time_channel else chart, model, eval_cfg=eval_cfg, floor_draws=floor_draws)
    return {"eps_q": float(gap["eps_q"]), "eps_q_floor": float(gap["floor"]["eps_q"]) if gap.get("floor") else math.nan, "chart_map_rms": rms}


def true_control_diagnosis(chart: Any, truth_npz: str | Path, system: str, diagnose_cfg: Any | None = None) -> Any:
    """The diagnosis's selection with a perfect model of the control class: the clip's control law in its chart.

    :func:`lagsplat.diagnose.diagnose_chart` on the chart's frames of ``diagnose_cfg.split`` with the law of
    :func:`law_in_chart` (``control=True``) as the model (its natural frequency, :meth:`TrueLawInChart.modal_analysis`,
    is the model's modal frequency there).
    Its residual is then the clip's effect and the chart's noise and bend only: no Stage-2 misfit. What the
    selection names on it is what the diagnosis can name on this chart and these frames at best (its ceiling
    for a Stage 2 that learned the control law exactly); the refit choice and the report's checks are not run.

    Args:
        chart, truth_npz, system: as for :func:`law_in_chart`.
        diagnose_cfg: the :class:`lagsplat.diagnose.report.DiagnoseConfig` (default settings when ``None``).

    Returns:
        The :class:`~lagsplat.diagnose.diagnosis.Diagnosis` (``winner``: the effect named, or ``"none"``).

    Raises:
        ValueError: as :func:`law_in_chart`.
    """
    from lagsplat.diagnose import diagnose_chart
    from lagsplat.diagnose.report import DiagnoseConfig
    from lagsplat.diagnose.where import split_code

    cfg = diagnose_cfg or DiagnoseConfig()
    model, _, _ = law_in_chart(chart, truth_npz, system, control=True)
    return diagnose_chart(model, chart, split_code(cfg.split), cfg.sigma, **cfg.select)[0]

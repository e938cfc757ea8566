"""The state behind the interactive viewer: an identified model you can grab and drag.

A :class:`Session` holds one latent state ``(q, qdot)`` of a trained system
(Stage-1 autoencoder, frozen chart, Stage-2 Lagrangian) and advances it in
fixed steps of the clip's frame interval. It knows nothing about the web: the
page (:mod:`lagsplat.viewer.server`) forwards pointer events to
:meth:`Session.press`, :meth:`Session.move` and :meth:`Session.release`,
slider changes to :meth:`Session.set_params`, and shows :meth:`Session.render`.

The drag (paper §3.4, Eq. 9). At the press the brush selects the material
under the pointer (:meth:`~lagsplat.forces.transport.ForceTransport.select`, radius
``sigma`` px) and freezes the selection until the release. While held, a
spring pulls the selected material's application point ``p(q)`` towards the
pointer ``x``:

    f = force_scale * (x - p(q))          (pixel force, image axes x right, y down)
    f_lat = kappa * sum_i w_i J_i^T f     (generalized force, :meth:`ForceTransport.pullback`)

and the state follows the edited dynamics
(:class:`~lagsplat.forces.transport.EditedDynamics`: inertia, damping and stiffness
factors) integrated by velocity Verlet
(:func:`~lagsplat.dynamics.integrators.verlet_step`). The spring force is
evaluated at every force evaluation of the integrator (not frozen over a
step), so the drag is itself integrated symplectically; a step of length
``dt`` is split into as many sub-steps as the stiffest linearised mode of the
loaded system needs (``omega h <= 0.5``, at most ``max_substeps``).

Units: pixels of the training resolution for every image position and pixel
force; ``q`` in whitened chart units; time in seconds.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from lagsplat.artifacts import Artifacts
from lagsplat.dynamics.integrators import initial_state, verlet_step
from lagsplat.forces.transport import EditedDynamics, ForceTransport, Selection
from lagsplat.io.clip import TRAIN
from lagsplat.viewer.drag import CompiledDraggedDynamics, DraggedDynamics
from lagsplat.viewer.mobility import Mobility

__all__ = ["PARAM_RANGE", "Session", "load_session"]

PARAM_RANGE = (0.25, 4.0)
"""Allowed range of the inertia, damping and stiffness factors (the page's sliders)."""

_DIVERGED = 1e4  # |q| beyond this many chart units: the integration blew up; the state is reset


class Session(Mobility):
    """One interactive simulation of an identified system (thread-safe).

    Args:
        ae: Stage-1 :class:`~lagsplat.models.autoencoder.AutoEncoder` (``decode``,
            ``decoder``, ``height``, ``width``).
        chart: the frozen :class:`~lagsplat.chart.Chart` (``to_raw``, ``W_inv``,
            ``mean``, ``q``, ``t``, ``split``).
        model: Stage-2 :class:`~lagsplat.models.lagrangian.Lagrangian` (eval mode).
        sigma: brush radius, pixels (> 0).
        force_scale: drag stiffness, pixel force per pixel of stretch, or
            ``"auto"``: the value at which the drag, held at the most mobile
            point of the rest image, is as stiff as the model's stiffest mode
            (``lambda_max(d2V/dq2) / (kappa max_x |J_bar(x)|^2)``; see
            :meth:`auto_force_scale`). The page's slider moves it
            by 0.1x .. 10x around this default.
        kappa: energy factor of the model's forces (:func:`~lagsplat.forces.transport.calibrate_kappa`; 1 = uncalibrated).
        initial: ``"rest"`` (``model.q_rest``, at rest) or ``"held_out"`` (the
            first held-out encoded frame with its finite-difference velocity;
            the rest state when the chart has none).
        dt: step in seconds (default: the clip's median frame interval).
        render_scale: render at this multiple of the training resolution (pointer
            coordinates stay in training pixels).
        max_substeps: upper bound of the integrator sub-steps per step.
        fast: integrate with the compiled kernels of :mod:`lagsplat.dynamics.fast`
            (float64, cheaper per step, benchmarks/rollout.py; same scheme and equations).
            ``None``: when the model supports them (scalar / constant inertia, no
            actuation); ``False``: always the torch path.

    Attributes:
        dt: step, seconds. ``height``, ``width``: training resolution, px.
        render_height, render_width: size of :meth:`render`'s images, px.
        q, qdot: current state ``[1,d]`` (read through :meth:`state`).

    Raises:
        ValueError: on a non-positive ``sigma``, ``dt``, ``kappa`` or ``render_scale``, or an unknown ``initial``.
    """

    def __init__(
        self,
        ae,
        chart,
        model,
        sigma: float = 2.0,
        force_scale: float | str = "auto",
        kappa: float = 1.0,
        initial: str = "rest",
        dt: float | None = None,
        render_scale: float = 1.0,
        max_substeps: int = 8,
        fast: bool | None = None,
    ) -> None:
        if not sigma > 0:
            raise ValueError(f"brush radius sigma must be positive (pixels), got {sigma}")
        if not (kappa > 0 and math.isfinite(kappa)):
            raise ValueError(f"kappa must be positive, got {kappa}")
        if not render_scale > 0:
            raise ValueError(f"render_scale must be positive, got {render_scale}")
        if initial not in ("rest", "held_out"):
            raise ValueError(f"initial must be 'rest' or 'held_out', got {initial!r}")
        self.ae, self.chart, self.model = ae, chart, model.eval()
        self.sigma, self.kappa, self.max_substeps = float(sigma), float(kappa), max(1, int(max_substeps))
        self.height, self.width = int(ae.height), int(ae.width)
        self.render_height = max(1, round(self.height * render_scale))
        self.render_width = max(1, round(self.width * render_scale))
        self.dt = float(dt) if dt is not None else _frame_interval(chart.t)
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise ValueError(f"time step must be positive (seconds), got {self.dt}")
        self.transport = ForceTransport.from_autoencoder(ae, chart)
        self.d = self.transport.d
        self._q_train = torch.as_tensor(np.asarray(chart.q, np.float32)[np.asarray(chart.split) == TRAIN])
        self._W_inv = torch.as_tensor(chart.W_inv, dtype=torch.float32)
        self._geom = None  # the frozen decoder's geometry, built at the first render
        self._mean = torch.as_tensor(chart.mean, dtype=torch.float32)
        with torch.no_grad():
            self.q_rest = model.q_rest.detach().reshape(1, -1).float().clone()
            self._M = model.mass_matrix(self.q_rest)[0].double()
            self._C = model.dissipation_matrix(self.q_rest)[0].double()
        self._H = model.potential_hessian(self.q_rest)[0].double()
        self._fm = None
        if fast is not False:
            from lagsplat.dynamics.fast import cached_export, unsupported_reason

            why = unsupported_reason(model)
            if why is None:
                self._fm = cached_export(model)
            elif fast:
                raise ValueError(f"fast=True but the compiled dynamics cannot be used: {why}")
        self.force_scale_default = self.auto_force_scale() if force_scale == "auto" else float(force_scale)
        if not (self.force_scale_default > 0 and math.isfinite(self.force_scale_default)):
            raise ValueError(f"force_scale must be positive or 'auto', got {force_scale}")
        self.params = {"inertia": 1.0, "damping": 1.0, "stiffness": 1.0, "force_scale": self.force_scale_default}
        self._lock = threading.RLock()
        self._sel: Selection | None = None
        self._target: Tensor | None = None
        self._seen = 0.0
        self.initial = initial
        self.diverged = 0
        self.steps = 0
        self.t = 0.0
        self.step_ms = 0.0
        self.render_ms = 0.0
        self._set_initial()
        self._substeps = self._count_substeps()

    # ------------------------------------------------------------ set-up
    def _set_initial(self) -> None:
        q0, v0 = self.q_rest.clone(), torch.zeros_like(self.q_rest)
        if self.initial == "held_out":
            idx = np.flatnonzero(np.asarray(self.chart.split) == 1)
            if len(idx) and idx[0] + 2 < len(self.chart.q):
                q0, v0 = initial_state(np.asarray(self.chart.q, np.float64), idx[:1], self.dt)
        self.q, self.qdot = q0.reshape(1, -1).float(), v0.reshape(1, -1).float()

    # ------------------------------------------------------------ interaction
    def _point(self, x: float, y: float) -> Tensor:
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"pointer position must be finite, got ({x}, {y})")
        return torch.tensor([[float(x), float(y)]], dtype=torch.float32)

    def press(self, x: float, y: float) -> bool:
        """Grab the material under the brush at ``(x, y)`` px (training resolution).

        The selection is frozen until :meth:`release`. Returns whether anything
        was selected (``False`` where the brush reaches no primitive: nothing is held).
        """
        with self._lock:
            pt = self._point(x, y)
            sel = self.transport.select(self.q, pt, self.sigma)
            if float(sel.weights.sum()) <= 0:
                self._sel, self._target = None, None
            else:
                self._sel, self._target = sel, pt
                self._seen = float(self.transport.observed_motion(sel, self._q_train)[0])
            self._substeps = self._count_substeps()
            return self._sel is not None

    def move(self, x: float, y: float) -> None:
        """Move the pointer to ``(x, y)`` px; the held material is pulled towards it (no-op when nothing is held)."""
        with self._lock:
            if self._sel is not None:
                self._target = self._point(x, y)

    def release(self) -> None:
        """Let go: the state evolves freely from where it is."""
        with self._lock:
            self._sel, self._target = None, None
            self._substeps = self._count_substeps()

    @property
    def grabbing(self) -> bool:
        """Whether material is held."""
        return self._sel is not None

    def set_params(self, inertia: float | None = None, damping: float | None = None, stiffness: float | None = None, force_scale: float | None = None) -> dict:
        """Change the edit factors (each clamped to :data:`PARAM_RANGE`) and/or the drag's ``force_scale`` (px force per px, > 0).

        ``None`` leaves a value unchanged. Returns the parameters now in force.

        Raises:
            ValueError: on a non-finite or non-positive value.
        """
        with self._lock:
            for name, v in (("inertia", inertia), ("damping", damping), ("stiffness", stiffness), ("force_scale", force_scale)):
                if v is None:
                    continue
                v = float(v)
                if not (v > 0 and math.isfinite(v)):
                    raise ValueError(f"{name} must be positive and finite, got {v}")
                self.params[name] = v if name == "force_scale" else min(max(v, PARAM_RANGE[0]), PARAM_RANGE[1])
            self._substeps = self._count_substeps()
            return dict(self.params)

    def reset(self) -> None:
        """Back to the rest state ``model.q_rest`` with zero velocity; lets go of any grab."""
        with self._lock:
            self.q, self.qdot = self.q_rest.clone(), torch.zeros_like(self.q_rest)
            self._sel, self._target = None, None
            self._substeps = self._count_substeps()

    # ------------------------------------------------------------ time stepping
    def _system(self):
        p = self.params
        if self._fm is not None:
            drag = None
            if self._sel is not None:
                w = self._sel.weights[0].double()
                c_bar = (w @ self.transport.c.double()).numpy()
                J_bar = torch.einsum("k,kid->id", w, self.transport.J.double()).numpy()
                drag = (c_bar, J_bar, self._target[0].double().numpy(), p["force_scale"], self.kappa)
            return CompiledDraggedDynamics(self._fm, p["inertia"], p["damping"], p["stiffness"], drag)
        dyn = EditedDynamics(self.model, p["inertia"], p["damping"], p["stiffness"])
        if self._sel is None:
            return dyn
        return DraggedDynamics(dyn, self.transport, self._sel, self._target, p["force_scale"], self.kappa)

    def step(self, n: int = 1) -> None:
        """Advance ``n`` steps of ``dt`` seconds (each split into the needed sub-steps).

        A state that becomes non-finite or leaves the chart by more than
        ``1e4`` units is put back at rest (counted in ``state()["diverged"]``).
        """
        with self._lock:
            t0 = time.perf_counter()
            with torch.no_grad():
                for _ in range(n):
                    system, k = self._system(), self._substeps
                    h = self.dt / k
                    q, v = self.q, self.qdot
                    if self._fm is not None:
                        q, v = q.double().numpy(), v.double().numpy()
                    for _ in range(k):
                        q, v = verlet_step(system, q, v, h)
                    if self._fm is not None:
                        q, v = torch.from_numpy(q).float(), torch.from_numpy(v).float()
                    if not (bool(torch.isfinite(q).all() & torch.isfinite(v).all()) and float(q.abs().max()) < _DIVERGED):
                        self.diverged += 1
                        q, v = self.q_rest.clone(), torch.zeros_like(self.q_rest)
                    self.q, self.qdot = q.detach(), v.detach()
                    self.steps += 1
                    self.t += self.dt
            ms = (time.perf_counter() - t0) * 1e3 / max(n, 1)
            self.step_ms = ms if self.steps <= n else 0.9 * self.step_ms + 0.1 * ms

    # ------------------------------------------------------------ output
    def state(self) -> dict:
        """JSON-ready snapshot.

        Keys: ``t`` (s), ``step``, ``q``, ``qdot``, ``q_rest`` (lists of ``d``
        floats), ``dist_rest`` (``|q - q_rest|``), ``grab`` (``None`` or
        ``{"point": [x, y], "pointer": [x, y], "force": [fx, fy], "seen_px": s}``:
        the held material's application point, the pointer, the pixel force,
        all px, and how far that material moved in the training clip, rms px
        (:meth:`~lagsplat.forces.transport.ForceTransport.observed_motion`: below about a
        pixel the video barely constrains its Jacobians)),
        ``params``, ``force_scale_default``, ``substeps``, ``compiled`` (the
        compiled dynamics are in use), ``size``
        (``[W, H]`` training px), ``render_size``, ``dt``, ``diverged``,
        ``step_ms``, ``render_ms``.
        """
        with self._lock:
            q = self.q
            grab = None
            if self._sel is not None:
                p = self.transport.application_point(q, self._sel)[0]
                f = self.params["force_scale"] * (self._target[0] - p)
                grab = {"point": p.tolist(), "pointer": self._target[0].tolist(), "force": f.tolist(), "seen_px": self._seen}
            return {
                "t": self.t,
                "step": self.steps,
                "q": q[0].tolist(),
                "qdot": self.qdot[0].tolist(),
                "q_rest": self.q_rest[0].tolist(),
                "dist_rest": float((q - self.q_rest).norm()),
                "grab": grab,
                "params": dict(self.params),
                "force_scale_default": self.force_scale_default,
                "substeps": self._substeps,
                "compiled": self._fm is not None,
                "size": [self.width, self.height],
                "render_size": [self.render_width, self.render_height],
                "dt": self.dt,
                "diverged": self.diverged,
                "step_ms": self.step_ms,
                "render_ms": self.render_ms,
            }

    def render(self, q: Tensor | None = None) -> np.ndarray:
        """Decode the current state (or ``q [1,d]``) to a uint8 image ``[render_height, render_width, 3]`` (RGB)."""
        if q is None:
            with self._lock:
                q = self.q.clone()
        t0 = time.perf_counter()
        with torch.no_grad():
            z = q.reshape(1, -1).float() @ self._W_inv + self._mean
            if self._geom is None:
                self._geom = self.ae.decoder.geometry()
            img = self.ae.decoder(z, self.render_height, self.render_width, geom=self._geom)[0]
            out = (img.clamp(0, 1).permute(1, 2, 0) * 255.0 + 0.5).to(torch.uint8).numpy()
        ms = (time.perf_counter() - t0) * 1e3
        self.render_ms = ms if self.render_ms == 0 else 0.9 * self.render_ms + 0.1 * ms
        return out

    def snapshot(self) -> tuple[np.ndarray, dict]:
        """``(render(), state())`` of one and the same state (the simulation may step meanwhile)."""
        with self._lock:
            q, st = self.q.clone(), self.state()
        return self.render(q), st


def _frame_interval(t) -> float:
    """Median positive interval of the timestamps ``t`` (seconds)."""
    dts = np.diff(np.asarray(t, np.float64))
    dts = dts[dts > 0]
    if not len(dts):
        raise ValueError("the chart's timestamps give no positive frame interval: pass dt")
    return float(np.median(dts))


def load_session(artifacts: Artifacts | str | Path, **kwargs) -> Session:
    """A :class:`Session` on the artifacts of one system.

    Args:
        artifacts: the run's :class:`~lagsplat.artifacts.Artifacts` (``stage1.pt``, ``chart.npz``,
            ``stage2.pt``), or a ``results/<system>/`` folder in the standard layout.
        **kwargs: passed to :class:`Session`.

    Raises:
        FileNotFoundError: naming the missing artifact.
    """
    a = artifacts if isinstance(artifacts, Artifacts) else Artifacts.at(artifacts)
    a.require("stage1", "chart", "stage2")
    model, _ = a.load_stage2()
    return Session(a.load_stage1(), a.load_chart(), model, **kwargs)

"""Simulation of the soft robot under a pressure schedule, frame by frame at the recordings' rate.

Part of :mod:`lagsplat.synth.continuum_robot` (its docstring describes the model).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lagsplat.synth.continuum_robot.constants import DEFAULT_DURATION_S, DT, FPS
from lagsplat.synth.continuum_robot.kernels import integrate_robot
from lagsplat.synth.continuum_robot.model import ContinuumRobot, check_segments
from lagsplat.synth.continuum_robot.pressure import PressureSchedule


def n_frames_for(duration_s: float, fps: float = FPS) -> int:
    """Frames of a clip of ``duration_s`` seconds at ``fps`` Hz.

    Raises:
        ValueError: if that is fewer than 16 frames.
    """
    n = round(duration_s * fps)
    if n < 16:
        raise ValueError(f"duration_s = {duration_s!r} gives {n} frames; need at least 16")
    return n


def simulate_frames(robot: ContinuumRobot, schedule: Any, n_frames: int, n_substeps: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Integrate from ``q_rest`` at rest; returns ``(states [T, 2d], pressures [T, 2n])`` at ``t_i = i DT``.

    ``schedule`` is a :class:`PressureSchedule` or any callable mapping times
    ``[m]`` (s) to pressures ``[m, 2n]``; it is evaluated at every RK4 stage time.
    """
    if isinstance(n_substeps, bool) or int(n_substeps) != n_substeps or int(n_substeps) < 1:
        raise ValueError(f"n_substeps must be an integer >= 1, got {n_substeps!r}")
    n_sub = int(n_substeps)
    h = DT / n_sub
    t_half = np.arange(2 * n_sub * (n_frames - 1) + 1) * (0.5 * h)
    P_half = np.ascontiguousarray(schedule(t_half), dtype=np.float64)
    if P_half.shape != (t_half.shape[0], 2 * robot.n_segments) or not np.all(np.isfinite(P_half)):
        raise ValueError(f"the pressure schedule must give finite [m, {2 * robot.n_segments}] pressures, got shape {P_half.shape}")
    modal = robot.modal
    ar = robot._arrays
    y0 = np.concatenate([modal.q_rest, np.zeros(robot.d)])
    Y = integrate_robot(y0, P_half, n_frames, n_sub, h, ar["L0"], robot.n_nodes, ar["mass"], ar["kdiag"], modal.damping, ar["B"], robot.gravity)
    if not np.all(np.isfinite(Y)):
        raise ValueError("the continuum-robot integration diverged (non-finite state); lower p_max or the actuation gains")
    return Y, P_half[:: 2 * n_sub].copy()


def simulate_continuum_robot(
    n_segments: int,
    duration_s: float = DEFAULT_DURATION_S,
    seed: int = 0,
    *,
    robot: ContinuumRobot | None = None,
    n_substeps: int = 4,
    **schedule_kwargs: Any,
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate the pressure-driven robot from rest, sampled at 59.94 fps.

    Args:
        n_segments: 1 or 2.
        duration_s: clip length (s); ``T = round(duration_s * FPS)`` frames.
        seed: seeds the pressure schedule (:meth:`PressureSchedule.random`).
        robot: the :class:`ContinuumRobot` (default :meth:`ContinuumRobot.default`);
            its ``n_segments`` must match.
        n_substeps: RK4 steps per frame interval (>= 1).
        **schedule_kwargs: keyword arguments of :meth:`PressureSchedule.random`
            (``p_max``, ``head_s``, ``tail_s``, ``rest_s``, ``n_rest``, ...).

    Returns:
        ``(states, pressures)``: float64 ``[T, 2d]`` states ``(q, qdot)``
        with ``q = (theta_1, eps_1[, theta_2, eps_2])`` (rad, strain) and
        ``qdot`` their rates (1/s), frame ``i`` at ``t_i = i * DT``; float64
        ``[T, 2 n]`` chamber pressures ``p1..p_2n`` (normalised by 101 325 Pa).

    Raises:
        ValueError: on invalid arguments (see :meth:`PressureSchedule.random`),
            a robot with another number of segments, or a diverging integration.
    """
    n = check_segments(n_segments)
    rob = ContinuumRobot.default(n) if robot is None else robot
    if not isinstance(rob, ContinuumRobot) or rob.n_segments != n:
        raise ValueError(f"robot must be a ContinuumRobot with {n} segment(s), got {robot!r}")
    sched = PressureSchedule.random(n, duration_s, seed, **schedule_kwargs)
    return simulate_frames(rob, sched, n_frames_for(sched.duration_s), n_substeps)



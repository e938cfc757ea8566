"""Ground-truth motion of an impact oscillator: a 1-DOF oscillator that bounces off rigid stops.

Between contacts the object follows the law of its system in the diagnosis library
(:mod:`lagsplat.synth.effects`, no effect)::

    x'' = -w0^2 g(x) - 2 zeta w0 x'        (g = sin for the pendulum, g(x) = x otherwise)

At a stop ``x_s`` the contact is instantaneous and rigid: the velocity reverses and shrinks by the
coefficient of restitution ``e`` (``v+ = -e v-``, ``0 < e < 1``). There is one stop (one-sided) or one
on each side of the release state (two-sided). :func:`impact_trajectory` integrates the smooth part
with ``scipy.integrate.solve_ivp`` (DOP853, ``rtol`` 1e-10, at most one frame per step), stops it at
each contact with a terminal event, applies the impact and restarts; turning points are recorded by a
second (non-terminal) event. It samples at the given frame times.

Small rebounds: a rebound slower than ``v_rest`` counts as none. If the smooth law then presses
the object into the stop (a stop between the release and the rest position, the spring loaded
against it), the object rests against the stop from then on; this ends the chattering (the
rebounds shorten in geometric progression and would otherwise accumulate infinitely many impacts in
finite time). If the law pulls it away (a stop beyond the rest position, grazed at the end of a swing),
it leaves the stop from rest and the free motion goes on.

Per frame, the hidden acceleration (what the nominal oscillator does not explain) is the impulse of
the impacts in the frame's interval ``[t_i - dt/2, t_i + dt/2)`` over ``dt`` (the mean of the contact
force's acceleration there), plus, while the object rests against a stop, the stop's reaction
``w0^2 g(x_s)`` that holds it; zero elsewhere.

Units: ``x`` in the clip's coordinate (rad or m), s, Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ["ImpactRun", "impact_trajectory", "observed_frequency", "MAX_IMPACTS"]

MAX_IMPACTS = 20000
"""Contacts :func:`impact_trajectory` resolves before it gives up (a finite-time pile-up the rest rule did not catch)."""


@dataclass
class ImpactRun:
    """One impact-oscillator trajectory, sampled at the frames.

    Attributes:
        t: ``[T]`` frame times, s.
        x: ``[T]`` position (the clip's coordinate).
        xdot: ``[T]`` its rate, per s (the post-impact rate at a frame that falls on an impact).
        hidden: ``[T]`` hidden acceleration per frame (module docstring), per s^2.
        impact_t: ``[n]`` contact times, s.
        impact_stop: ``[n]`` index into ``stops`` of each contact.
        v_pre, v_post: ``[n]`` rates just before and after each contact (``v_post = -e v_pre``, or 0 when the
            rebound is below ``v_rest``).
        turn_t: ``[m]`` smooth turning points (``x' = 0`` away from the stops), s.
        rest_s: when the object comes to rest against a stop, s; ``None`` if it never does in the take.
        stops: the stop positions.
    """

    t: np.ndarray
    x: np.ndarray
    xdot: np.ndarray
    hidden: np.ndarray
    impact_t: np.ndarray
    impact_stop: np.ndarray
    v_pre: np.ndarray
    v_post: np.ndarray
    turn_t: np.ndarray
    rest_s: float | None
    stops: tuple[float, ...] = field(default_factory=tuple)


def _stop_sides(stops: tuple[float, ...], x0: float) -> tuple[float, ...]:
    """``+1`` for a stop above ``x0`` (it blocks upward motion), ``-1`` below; raises on a bad layout."""
    if not 1 <= len(stops) <= 2:
        raise ValueError(f"need one or two stops, got {len(stops)}")
    if any(s == x0 for s in stops):
        raise ValueError(f"the release position {x0} lies on a stop {stops}; it must be on the free side")
    sides = tuple(1.0 if s > x0 else -1.0 for s in stops)
    if len(stops) == 2 and sides[0] == sides[1]:
        raise ValueError(f"two stops {stops} on the same side of the release position {x0}: one would never be met")
    return sides


def impact_trajectory(
    w0: float, zeta: float, sine: bool, stops: tuple[float, ...], e: float, x0: float, v0: float, t: np.ndarray, v_rest: float | None = None
) -> ImpactRun:
    """Integrate the impact oscillator of the module docstring from ``(x0, v0)`` at ``t[0]`` and sample it at ``t``.

    Args:
        w0: natural angular frequency, rad/s (``> 0``).
        zeta: damping ratio of the smooth part (``>= 0``).
        sine: ``g = sin`` (pendulum) instead of ``g(x) = x``.
        stops: one or two stop positions; with two, one on each side of ``x0``.
        e: coefficient of restitution, ``0 < e < 1``.
        x0, v0: release state (``x0`` strictly on the free side of every stop).
        t: ``[T]`` equally spaced sample times, s (``T >= 2``).
        v_rest: rebound speed counted as none (default ``1e-4 w0`` times the largest of ``|x0|``, ``|v0| / w0``
            and the stops' distances from 0).

    Returns:
        The :class:`ImpactRun`.

    Raises:
        ValueError: on bad arguments, a failed integration or more than :data:`MAX_IMPACTS` contacts.
    """
    t = np.asarray(t, np.float64)
    if t.ndim != 1 or len(t) < 2 or not np.all(np.diff(t) > 0):
        raise ValueError("t must be at least two increasing sample times")
    if not (w0 > 0 and zeta >= 0 and 0 < e < 1):
        raise ValueError(f"need w0 > 0, zeta >= 0 and 0 < e < 1; got {w0}, {zeta}, {e}")
    stops = tuple(float(s) for s in stops)
    sides = _stop_sides(stops, float(x0))
    dt = float(t[1] - t[0])
    g = math.sin if sine else (lambda v: v)
    if v_rest is None:
        v_rest = 1e-4 * w0 * max(abs(x0), abs(v0) / w0, *(abs(s) for s in stops))

    def rhs(_t: float, y: np.ndarray) -> list[float]:
        return [y[1], -w0 * w0 * g(y[0]) - 2.0 * zeta * w0 * y[1]]

    def contact(k: int):
        def ev(_t: float, y: np.ndarray) -> float:  # > 0 on the free side
            return sides[k] * (stops[k] - y[0])

        ev.terminal, ev.direction = True, -1
        return ev

    def turn(_t: float, y: np.ndarray) -> float:
        return y[1]

    events = [contact(k) for k in range(len(stops))] + [turn]
    x, xd, hidden = np.empty(len(t)), np.empty(len(t)), np.zeros(len(t))
    imp: list[tuple[float, int, float, float]] = []
    turns: list[float] = []
    t0, y, rest, first = float(t[0]), [float(x0), float(v0)], None, None
    while True:
        sol = solve_ivp(rhs, (t0, float(t[-1])), y, method="DOP853", events=events, dense_output=True,
                        rtol=1e-10, atol=1e-12, max_step=dt, first_step=first)  # fmt: skip
        if sol.status == -1:
            raise ValueError(f"impact oscillator integration failed: {sol.message}")
        hits = [(float(sol.t_events[k][0]), k) for k in range(len(stops)) if len(sol.t_events[k])]
        end, k = min(hits) if hits else (math.inf, -1)
        turns += [float(s) for s in sol.t_events[-1] if t0 + 1e-12 < s < end]
        seg = (t >= t0) & (t < end)
        if seg.any():
            x[seg], xd[seg] = sol.sol(t[seg])
        if not hits:
            break
        v_pre = float(sol.y_events[k][0][1])
        v_post = -e * v_pre
        pressed = sides[k] * -w0 * w0 * g(stops[k]) > 0  # the smooth law pushes the object into the stop
        if sides[k] * v_pre <= 0:  # a contact at the restart itself: a rebound too short to resolve
            if not pressed:
                raise ValueError(f"contact with stop {stops[k]} at {end:.6f} s while leaving it")
            v_post = 0.0
        if abs(v_post) < v_rest:
            v_post = 0.0
        imp.append((end, k, v_pre, v_post))
        if len(imp) > MAX_IMPACTS:
            raise ValueError(f"more than {MAX_IMPACTS} contacts by {end:.3f} s (chattering not caught; raise v_rest)")
        if end >= t[-1]:  # the take ends on the contact
            x[t >= end], xd[t >= end] = stops[k], v_post
            break
        if v_post == 0.0 and pressed:  # rests against the stop for the rest of the take
            rest = end
            held = t >= end
            x[held], xd[held] = stops[k], 0.0
            hidden[held] = w0 * w0 * g(stops[k])
            break
        a_s = abs(w0 * w0 * g(stops[k]))
        first = min(dt, float(t[-1]) - end, max(1e-9, 0.05 * 2 * abs(v_post) / a_s)) if pressed and a_s > 0 else None  # resolve short rebounds
        t0, y = end, [stops[k], v_post]
    it = np.array([i[0] for i in imp])
    vp, vq = np.array([i[2] for i in imp]), np.array([i[3] for i in imp])
    if len(imp):
        frame = np.clip(np.floor((it - t[0]) / dt + 0.5).astype(int), 0, len(t) - 1)
        np.add.at(hidden, frame, (vq - vp) / dt)
    return ImpactRun(t, x, xd, hidden, it, np.array([i[1] for i in imp], int), vp, vq, np.array(turns), rest, stops)


def observed_frequency(run: ImpactRun, until: float | None = None) -> float:
    """The frequency of the motion over its moving part, Hz: ``(n - 1) / (2 (t_n - t_1))`` over its ``n`` turning
    points (the contacts and the smooth turning points, up to the rest if it rests, and up to ``until``, s, if
    given); ``nan`` with fewer than 3.

    A contact reverses the motion as a turning point does, so a one-sided stop gives one contact and one
    smooth turning point per cycle, a two-sided stop two contacts, as the free oscillator gives two turning points.
    """
    tt = np.sort(np.concatenate([run.impact_t, run.turn_t]))
    end = min(math.inf if run.rest_s is None else run.rest_s, math.inf if until is None else until)
    tt = tt[tt <= end]
    return float((len(tt) - 1) / (2.0 * (tt[-1] - tt[0]))) if len(tt) >= 3 else float("nan")

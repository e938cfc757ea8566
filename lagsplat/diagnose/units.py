"""The identified motion in physical units: what a known length in the image (``system.scale``) turns it into.

Without any scale, the frequency alone gives two derived quantities, each with the frequency's interval carried
through (both are monotonic in ``f``): the stiffness-to-mass ratio ``k / m = (2 pi f)^2`` of a mass on a
spring, and the length ``g / (2 pi f)^2`` of the simple pendulum of that frequency (small swings). Which one
applies is the user's knowledge, not the video's; the report gives both, named.

With ``system.scale.points`` (two points in the source video's pixels) and ``metres`` (their distance), one
source pixel is ``metres / |p1 - p0|`` m, and the motion's amplitude (half the largest swing of the object's
fastest-moving visible part, read through the decoder at the chart's extremes, :func:`motion_amplitude_source_px`,
carried to source pixels through the clip's crop and resize) is given in metres. With ``pendulum_length_m`` as well, the amplitude is given in degrees
(arc / length) and the pendulum length the frequency implies is compared with the given one.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from lagsplat.evaluate.common import finite_number, metric_value

__all__ = ["G", "physical_quantities", "motion_amplitude_source_px", "metres_per_source_px"]

#: Standard gravity, m/s^2.
G = 9.80665
#: The amplitude is the opacity-weighted quantile at this level of the primitives' displacements: the fastest
#: visible part (a pendulum's bob, not the rod near its pivot).
FASTEST = 0.99


def metres_per_source_px(scale: Mapping[str, Any] | None) -> float | None:
    """Metres per source pixel from ``system.scale`` (``points`` ``[x0, y0, x1, y1]`` and ``metres``), or ``None``.

    Raises:
        ValueError: if the two points coincide, or only one of ``points`` / ``metres`` is given.
    """
    if not scale:
        return None
    pts, m = scale.get("points"), scale.get("metres")
    if pts is None and m is None:
        return None
    if pts is None or m is None:
        raise ValueError("system.scale: give both points [x0, y0, x1, y1] (source pixels) and metres (their distance)")
    x0, y0, x1, y1 = (float(v) for v in pts)
    d = math.hypot(x1 - x0, y1 - y0)
    if d <= 0:
        raise ValueError(f"system.scale.points {list(pts)}: the two points coincide")
    return float(m) / d


def motion_amplitude_source_px(tr: Any, chart: Any, meta: Mapping[str, Any] | None) -> float | None:
    """Half the largest swing of the object's fastest-moving part, source pixels.

    The chart's smallest and largest projection on ``G_bar``'s top direction (its extremes over the clip's frames)
    are decoded: each primitive's displacement between them (:meth:`~lagsplat.diagnose.screen.ScreenKinematics.positions`),
    carried to source pixels through the crop and resize in ``meta``, weighted by its smaller opacity of the two (a
    primitive the latent gate hides at one end draws nothing there); half the weighted :data:`FASTEST` quantile is
    the amplitude (a pendulum's bob, not the rod near its pivot). ``None`` when no primitive is visible at both ends.
    """
    import torch

    from lagsplat.diagnose.pixels import source_px_per_px
    from lagsplat.metrics import normalise_trace, project, top_direction

    top = top_direction(normalise_trace(chart.G_bar))
    q = np.asarray(chart.q, np.float32)
    p = project(q, top)
    ends = [torch.as_tensor(q[int(i)][None]) for i in (np.argmin(p), np.argmax(p))]
    with torch.no_grad():
        step = (tr.positions(ends[1]) - tr.positions(ends[0])).numpy().astype(float)  # [K, 2] working px
        w = torch.minimum(tr.opacity(ends[0])[0], tr.opacity(ends[1])[0]).numpy().astype(float)
    k = source_px_per_px(meta)
    if k is not None:
        step = step * k
    if not (w > 0).any():
        return None
    disp = np.hypot(step[:, 0], step[:, 1])
    order = np.argsort(disp)
    cum = np.cumsum(w[order]) / w.sum()
    return 0.5 * float(disp[order][min(int(np.searchsorted(cum, FASTEST)), len(disp) - 1)])


def physical_quantities(metrics: Mapping[str, Any], scale: Mapping[str, Any] | None, amplitude_px: float | None) -> list[dict]:
    """Rows ``{quantity, value, interval, units, method}`` (as :func:`lagsplat.diagnose.quantities.identified_quantities`).

    Args:
        metrics: ``metrics.json``'s ``metrics`` block (``f_sim_hz`` and its ``f_sim_hz_interval``).
        scale: ``system.scale`` (``points``, ``metres``, ``pendulum_length_m``) or ``None``.
        amplitude_px: :func:`motion_amplitude_source_px`, or ``None``.

    Raises:
        ValueError: as :func:`metres_per_source_px`.
    """
    f = finite_number(metric_value(metrics, "f_sim_hz"))
    f = f if f is not None and f > 0 else None
    iv = metric_value(metrics, "f_sim_hz_interval")
    rows: list[dict] = []
    if f is not None:
        w2 = lambda x: (2 * math.pi * x) ** 2  # noqa: E731
        carried = "the frequency's interval carried through" if iv else "no interval (the frequency has none)"
        rows.append({"quantity": "stiffness-to-mass ratio k/m = (2 pi f)^2 (a mass on a spring)", "value": w2(f),
                     "interval": [w2(iv[0]), w2(iv[1])] if iv else None, "units": "1/s^2", "method": carried})  # fmt: skip
        length = lambda x: G / w2(x)  # noqa: E731
        rows.append({"quantity": "length of the simple pendulum of this frequency g/(2 pi f)^2", "value": length(f),
                     "interval": [length(iv[1]), length(iv[0])] if iv else None, "units": "m", "method": carried})  # fmt: skip
    mpp = metres_per_source_px(scale)
    L = (scale or {}).get("pendulum_length_m")
    if mpp is not None and amplitude_px is not None:
        amp_m = amplitude_px * mpp
        how = f"half the largest swing, {amplitude_px:.1f} source px at {mpp:.4g} m per px (system.scale)"
        rows.append({"quantity": "amplitude", "value": amp_m, "interval": None, "units": "m", "method": how})
        if L:
            rows.append({"quantity": "amplitude (angle)", "value": math.degrees(amp_m / float(L)), "interval": None, "units": "deg",
                         "method": f"arc {amp_m:.4g} m over the pendulum length {float(L):g} m (system.scale)"})  # fmt: skip
    if L and f is not None:
        implied = G / (2 * math.pi * f) ** 2
        rows.append({"quantity": "implied over given pendulum length", "value": implied / float(L), "interval": None, "units": "1",
                     "method": f"g/(2 pi f)^2 = {implied:.4g} m against {float(L):g} m (1: an ideal simple pendulum at small swings; a heavy rod reads below 1, large swings above)"})  # fmt: skip
    return rows

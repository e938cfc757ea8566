"""90 % intervals for the identified frequency and damping ratio: split-conformal, scaled per clip.

The error of an identified frequency against the truth has two parts: how far the model's
rollouts drift from the encoded video (which the clip itself shows: ``eps_freq``), and how far
the chart's own motion sits from the physical one (which no single clip shows). An interval
from the spread of refits on one chart (a bootstrap, an ensemble) sees only the first part.
The interval here is calibrated against known truth instead, by split conformal prediction
(Vovk, Gammerman and Shafer 2005, *Algorithmic Learning in a Random World*; Lei et al. 2018,
"Distribution-free predictive inference for regression", JASA 113:1094), with a per-clip scale:

* frequency: ``f_sim * (1 +- k_f * s_f)`` with ``s_f = eps + FLOOR_FREQ``, ``eps`` the clip's own
  model-against-video frequency disagreement (``eps_freq`` on held-out frames, ``eps_freq_in_sample``
  for a clip identified on all its frames);
* damping ratio: ``zeta_sim +- k_z * s_z`` with ``s_z = |zeta_sim - zeta_enc| + FLOOR_ZETA``.

``k`` is the ``ceil((n + 1) * level)``-th smallest of the scores ``|f_truth / f_sim - 1| / s_f``
(``|zeta_sim - zeta_truth| / s_z``) over ``n`` calibration clips of known truth (the rendered
realistic suite's calibration half; ``benchmarks/intervals.py`` writes :data:`CALIBRATION_FILE`
with the clips, the commit and the coverage it measured on the other half). The guarantee is
marginal, over clips like the calibration clips (exchangeable with them); a recording unlike
them (another kind of system, another camera) is not covered by it, and the interval says so in
its definition.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from lagsplat.evaluate.common import finite_number, metric_entry, metric_value

__all__ = ["CALIBRATION_FILE", "FLOOR_FREQ", "FLOOR_ZETA", "LEVEL", "conformal_k", "frequency_scale", "damping_scale", "load_calibration", "intervals"]

#: The calibration the package ships (written by ``benchmarks/intervals.py --calibrate``).
CALIBRATION_FILE = Path(__file__).with_name("interval_calibration.json")
#: The nominal coverage of the intervals.
LEVEL = 0.9
#: Added to a clip's relative frequency disagreement (a clip whose rollouts match the video exactly is still
#: read through a chart; fixed before calibration, not fitted).
FLOOR_FREQ = 0.002
#: Added to a clip's damping-ratio disagreement (absolute; fixed before calibration, not fitted).
FLOOR_ZETA = 0.002


def _value(m: Mapping[str, Any], key: str) -> float | None:
    return finite_number(metric_value(m, key))


def frequency_scale(m: Mapping[str, Any]) -> float | None:
    """A clip's frequency scale ``s_f`` (relative) from its ``metrics`` block, or ``None`` without one."""
    eps = _value(m, "eps_freq")
    eps = _value(m, "eps_freq_in_sample") if eps is None else eps
    return None if eps is None else eps + FLOOR_FREQ


def damping_scale(m: Mapping[str, Any]) -> float | None:
    """A clip's damping scale ``s_z`` (absolute) from its ``metrics`` block, or ``None`` without both ratios."""
    z_sim, z_enc = _value(m, "zeta_sim"), _value(m, "zeta_enc")
    return None if z_sim is None or z_enc is None else abs(z_sim - z_enc) + FLOOR_ZETA


def conformal_k(scores: Sequence[float], level: float = LEVEL) -> float:
    """The split-conformal quantile: the ``ceil((n + 1) level)``-th smallest of ``n`` scores (``inf`` when
    ``n`` is too small for ``level``: no finite interval has the guarantee)."""
    s = np.sort(np.asarray([x for x in scores if math.isfinite(x)], float))
    r = math.ceil((len(s) + 1) * level)
    return float(s[r - 1]) if 0 < r <= len(s) else float("inf")


def load_calibration(path: str | Path = CALIBRATION_FILE) -> dict | None:
    """The calibration (``k_freq``, ``k_zeta``, ``level``, ``clips``, ``commit``, ``coverage``), or ``None`` if absent.

    Raises:
        ValueError: naming the file if it is not a calibration (no ``k_freq``/``k_zeta``).
    """
    p = Path(path)
    if not p.exists():
        return None
    cal = json.loads(p.read_text())
    if not {"k_freq", "k_zeta"} <= set(cal):
        raise ValueError(f"{p}: not an interval calibration (needs k_freq and k_zeta)")
    return cal


def intervals(m: Mapping[str, Any], calibration: Mapping[str, Any] | None) -> dict[str, dict]:
    """``f_sim_hz_interval`` and ``zeta_sim_interval`` (``[low, high]``) for a ``metrics`` block (module docstring).

    Args:
        m: the ``metrics`` block (``f_sim_hz``, ``eps_freq`` or ``eps_freq_in_sample``, ``zeta_sim``, ``zeta_enc``).
        calibration: :func:`load_calibration`'s mapping; ``None``: no interval (the entries say why).

    Returns:
        name -> :func:`~lagsplat.evaluate.common.metric_entry`; a value is ``None`` where the clip lacks a
        quantity (no oscillation in the held-out frames, fewer than three half cycles for a damping ratio).
    """
    if calibration is None:
        why = f"no interval: the package has no calibration ({CALIBRATION_FILE.name}; benchmarks/intervals.py --calibrate writes it)"
        return {"f_sim_hz_interval": metric_entry(None, why, "", "Hz"), "zeta_sim_interval": metric_entry(None, why, "", "1")}
    level = float(calibration.get("level", LEVEL))
    where = (f"split-conformal {100 * level:.0f} % interval (lagsplat.evaluate.intervals), k calibrated on {len(calibration.get('clips', []))} "
             f"rendered clips of known truth at commit {calibration.get('commit', '?')}; holds for clips like those, marginally")  # fmt: skip
    out: dict[str, dict] = {}
    f, s_f = _value(m, "f_sim_hz"), frequency_scale(m)
    k_f = float(calibration["k_freq"])
    out["f_sim_hz_interval"] = metric_entry(
        None if f is None or s_f is None else [f * (1 - k_f * s_f), f * (1 + k_f * s_f)],
        f"f_sim * (1 -+ k s), s = frequency disagreement + {FLOOR_FREQ:g}, k = {k_f:.3g}; {where}", "", "Hz")  # fmt: skip
    z, s_z = _value(m, "zeta_sim"), damping_scale(m)
    k_z = float(calibration["k_zeta"])
    out["zeta_sim_interval"] = metric_entry(
        None if z is None or s_z is None else [z - k_z * s_z, z + k_z * s_z],
        f"zeta_sim -+ k s, s = |zeta_sim - zeta_enc| + {FLOOR_ZETA:g}, k = {k_z:.3g}; {where}", "", "1")  # fmt: skip
    return out

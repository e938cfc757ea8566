"""The identified quantities a report leads with, each with a 90 % interval and the method behind it.

* the natural frequency and the damping ratio of the identified model: ``metrics.json``'s ``f_sim_hz`` and
  ``zeta_sim`` with their split-conformal intervals (:mod:`lagsplat.evaluate.intervals`), and the linearised
  modes ``f_modes_hz`` / ``zeta_modes`` (no interval: the calibration is of the rollout's quantities);
* the coefficients of the effect the diagnosis names: value +- 1.645 standard errors of the residual
  regression (:mod:`lagsplat.diagnose.regression`), a normal approximation, not calibrated (the regression's
  standard errors assume independent residuals after the smoothing's effective sample size).
"""

from __future__ import annotations

from typing import Any, Mapping

from lagsplat.evaluate.common import finite_number, metric_value

__all__ = ["identified_quantities", "report_quantities", "quantities_section", "Z90"]

#: The two-sided 90 % point of the standard normal.
Z90 = 1.6448536269514722


def identified_quantities(metrics_json: Mapping[str, Any] | None, diagnosis: Mapping[str, Any] | None, verdict: str) -> list[dict]:
    """Rows ``{quantity, value, interval, units, method}`` (``interval`` ``[low, high]`` or ``None``).

    Args:
        metrics_json: the run's ``metrics.json`` (its ``metrics`` block read), or ``None``.
        diagnosis: ``report.json["diagnosis"]`` (``effects``: per effect its ``coefficients`` name -> value, se).
        verdict: the report's verdict; the coefficients of the effect it names are listed.
    """
    m = (metrics_json or {}).get("metrics", {})
    rows: list[dict] = []
    conformal = "split-conformal 90 % interval calibrated on rendered clips of known truth (lagsplat.evaluate.intervals)"
    for key, name, units in (("f_sim_hz", "natural frequency (free rollout)", "Hz"), ("zeta_sim", "damping ratio (free rollout)", "1")):
        v, iv = metric_value(m, key), metric_value(m, f"{key}_interval")
        if finite_number(v) is not None:
            why = conformal if iv is not None else ((m.get(f"{key}_interval") or {}).get("definition") or "no interval")
            rows.append({"quantity": name, "value": float(v), "interval": iv, "units": units, "method": why})
    for key, name, units in (("f_modes_hz", "linearised mode frequency", "Hz"), ("zeta_modes", "linearised mode damping ratio", "1")):
        for i, v in enumerate(metric_value(m, key) or []):
            if finite_number(v) is not None:
                rows.append({"quantity": f"{name} {i + 1}", "value": float(v), "interval": None, "units": units,
                             "method": "the model linearised at rest; no interval (the calibration is of the rollout's quantities)"})  # fmt: skip
    for eff in (diagnosis or {}).get("effects", []) or []:
        if eff.get("effect") != verdict:
            continue
        for cname, c in (eff.get("coefficients") or {}).items():
            val, se = c.get("value"), c.get("se")
            if finite_number(val) is not None:
                iv = [val - Z90 * se, val + Z90 * se] if finite_number(se) is not None else None
                rows.append({"quantity": f"{verdict}: {cname}", "value": float(val), "interval": iv, "units": "chart units",
                             "method": "value +- 1.645 standard errors of the residual regression (normal approximation, not calibrated)"})  # fmt: skip
    return rows


def report_quantities(
    metrics_json: Mapping[str, Any] | None, report: Mapping[str, Any], screen: Any | None, chart: Any, clip: Any | None, scale: Mapping[str, Any] | None
) -> list[dict]:
    """The report's ``identified`` rows: :func:`identified_quantities` of its verdict, then the physical units of
    :func:`lagsplat.diagnose.units.physical_quantities` (the motion's amplitude read through the decoder's
    :class:`~lagsplat.diagnose.screen.ScreenKinematics` ``screen`` where given, the clip's crop and resize in ``clip.meta``)."""
    from lagsplat.diagnose.units import motion_amplitude_source_px, physical_quantities

    amp = None if screen is None else motion_amplitude_source_px(screen, chart, getattr(clip, "meta", None))
    rows = identified_quantities(metrics_json, report.get("diagnosis"), str(report.get("verdict")))
    return rows + physical_quantities((metrics_json or {}).get("metrics", {}), scale, amp)


def quantities_section(rep: Mapping[str, Any]) -> list[str]:
    """``report.md``'s "Identified quantities" section from ``report.json["identified"]`` (empty without rows)."""
    rows = rep.get("identified") or []
    if not rows:
        return []
    L = ["", "## Identified quantities", "", "| quantity | value | 90 % interval | units | how the interval is made |", "|---|---|---|---|---|"]
    for r in rows:
        iv = r.get("interval")
        cell = f"{iv[0]:.4g} to {iv[1]:.4g}" if iv else "-"
        L.append(f"| {r['quantity']} | {r['value']:.4g} | {cell} | {r['units']} | {r['method']} |")
    return L

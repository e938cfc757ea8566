"""``report.md``: the diagnosis report rendered from its record (``report.json``), one function per section.

Sections, in order: verdict, evidence (paper §3.3 selection), what the
recording can and cannot tell (where the report carries it), where the gap
shows, the held-out gap, the refit (:mod:`lagsplat.diagnose.report` builds the
record; :func:`render_markdown` joins the sections).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from lagsplat.diagnose.quantities import quantities_section
from lagsplat.diagnose.reading import carried_nonlinearity_line, distinguishing_lines, not_significant_lines
from lagsplat.diagnose.refit import GAP_METRICS

__all__ = ["render_markdown", "fmt_value", "fmt_pct", "GAP_LABELS"]

GAP_LABELS = {
    "eps_q": "eps_q (latent NRMSE, 2 periods)",
    "eps_freq": "eps_freq (free-oscillation frequency error)",
    "envelope_decay_error": "envelope-decay error",
    "image_excess": "image error over the AE floor, (eps_I - eps_AE) / eps_AE",
    "eps_q_over_floor": "eps_q over the chart-noise floor, eps_q - eps_q_floor (what a model with no gap scores on this chart; lowest of the models compared)",
    "eps_freq_over_floor": "eps_freq over the chart-noise floor, eps_freq - eps_freq_floor (likewise)",
}
"""Row labels of the held-out gap metrics in the report."""


def _cv_cell(c: Mapping[str, Any]) -> str:
    """A ranking row's CV gain, with the candidate's own beside it where it was computed (a signature-confirmed candidate)."""
    own = c.get("cv_gain_own")
    return fmt_value(c["cv_gain"], ".2f") + ("" if own is None else f" (own {fmt_value(own, '.2f')})")


def fmt_value(x: Any, fmt: str = ".3g") -> str:
    """A report cell: ``n/a`` for None or non-finite, ``yes``/``no`` for booleans, numbers with ``fmt``."""
    if x is None:
        return "n/a"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, (int, float)):
        return format(x, fmt) if math.isfinite(x) else "n/a"
    return str(x)


def fmt_pct(x: Any) -> str:
    """A signed percentage of a fraction, or ``n/a``."""
    return "n/a" if x is None else f"{100 * x:+.0f} %"


def _reliability_lines(rel: Mapping[str, Any] | None) -> list[str]:
    """The warnings of :func:`~lagsplat.diagnose.report_checks.reliability` above the evidence (none when all checks pass)."""
    L: list[str] = []
    if rel and not rel["reliable"]:
        L += ["The chart does not support a diagnosis: improve Stage 1 first (a tighter crop, more steps or Gaussians, "
              "docs/preparation.md). The ranking below is what the residual says, kept as evidence, not a finding.", ""]  # fmt: skip
    if rel and rel.get("cautions"):
        L += ["Caution: " + "; ".join(rel["cautions"]) + ".", ""]
    return L


def _choice_line(choice: list[Mapping[str, Any]], base: float | None) -> str:
    """How the refits decided between significant candidates (:func:`~lagsplat.diagnose.refit_choice.choose_by_refit`)."""
    rows = ", ".join(f"{c['effect']} {fmt_value(c['train_rollout_nrmse'], '.3f')}" for c in choice)
    won, first = next(c for c in choice if c["chosen"]), choice[0]
    if first["train_rollout_nrmse"] is None:  # a winner with no Stage-2 refit (a missing degree of freedom)
        rival = choice[1]
        how = "is taken" if won is rival else f"is not taken: {first['effect']} stands"
        return (f"- the Delta-BIC winner {first['effect']} has no Stage-2 refit, and the residual cannot tell it from {rival['effect']} "
                f"(evidence within 2); a model refit with {rival['effect']} follows the training video "
                f"{'better' if rival['beats_identified'] else 'no better'} than the identified model (training-rollout NRMSE "
                f"{fmt_value(rival['train_rollout_nrmse'], '.3f')} against {fmt_value(base, '.3f')}, paper §3.3), so {rival['effect']} {how}.")  # fmt: skip
    if won is not first:
        how = f"is not confirmed (its refit follows the training video worse than the identified model), {won['effect']} is taken instead"
    elif first["beats_identified"]:
        how = "is confirmed"
    else:
        how = "stands (no candidate's refit follows the training video better than the identified model)"
    return (f"- several candidates are significant; the Delta-BIC winner {first['effect']} {how}, by the training-rollout NRMSE "
            f"of the model refit with {'it' if len(choice) == 1 else 'each'} (paper §3.3; identified model {fmt_value(base, '.3f')}): {rows}.")  # fmt: skip


def verdict_section(rep: Mapping[str, Any]) -> list[str]:
    """The title, the verdict with its reliability, the accepted effects and the model-choice line."""
    dg = rep["diagnosis"]
    L: list[str] = [f"# Sim-to-real gap diagnosis: {rep.get('title') or rep.get('system')}", ""]
    verdict = rep["verdict_text"]
    L += [f"**Verdict: {verdict}.**", ""]
    if rep.get("held_out"):  # a clip identified on all its frames (lagsplat.io.clip.Clip.no_held_out)
        L += [f"**{rep['held_out'][:1].upper() + rep['held_out'][1:]}**: the clip is too short for the held-out protocol and was "
              "identified on all its frames; the ranking below reads the training residual, and the held-out refit validation is skipped.", ""]  # fmt: skip
    L += _reliability_lines(rep.get("reliability"))
    null = dg["null"]
    if rep["verdict"] == "cannot_diagnose":
        ranked = (rep.get("residual_ranking") or {}).get("text", "")
        L.append(f"- the residual's own ranking (not a finding): {ranked}.")
    elif rep["verdict"] == "none":
        L.append(
            "No candidate effect explains the residual of the identified model significantly beyond the model-class "
            "corrections (rule: physical, Delta BIC plus its signature's support >= {min_delta_bic:g}, R2 >= {min_r2:g}, blocked-CV gain >= {min_cv_gain:g}).".format(**dg["settings"])
        )
        carried = carried_nonlinearity_line(dg)
        if carried:
            L.append(f"- {carried}.")
    else:
        for e in dg["effects"]:
            it = e.get("interpretation", {})
            L.append(f"- **{e['effect']}**: {it.get('text', '')}")
    L.append(f"- residual after the model-class corrections: {fmt_value(null.get('excess_after_effects', null['excess_over_noise']))} x the chart-noise variance "
             f"(null fit: {fmt_value(null['excess_over_noise'])}).")  # fmt: skip
    if null.get("warning"):
        L.append(f"- warning: {null['warning']}")
    if dg["settings"].get("cv_folds", 2) < 2:
        L.append(f"- warning: the {dg['settings'].get('n_samples')} residual samples make a single cross-validation block, so no candidate "
                 "can be significant; a longer clip (more training periods) is needed.")  # fmt: skip
    choice = (rep.get("refit") or {}).get("choice")
    if choice:
        L.append(_choice_line(choice, rep["refit"].get("baseline_train_rollout_nrmse")))
    if rep["verdict"] != "cannot_diagnose" and dg.get("evidence"):
        L += ["", "What tells the candidates apart on this clip:", "", *distinguishing_lines(dg)]
    check = (rep.get("gap") or {}).get("held_out_check")
    if check:
        L.append(f"- held-out check: {check['text']}.")
    return L


def evidence_section(rep: Mapping[str, Any]) -> list[str]:
    """The ranking of the candidate effects and their chart-invariant signatures."""
    dg = rep["diagnosis"]
    L: list[str] = []
    st = dg["settings"]
    smooth = ""
    if st.get("sigma_frames_out_of_class") is not None:  # the two regressions' smoothing (lagsplat.diagnose.select, "Band of the out-of-class regression")
        smooth = (f"; in-class candidates (end stop, cubic stiffness) on the residual smoothed over {fmt_value(st['sigma_frames'], '.2f')} frames, "
                  f"the other candidates over {fmt_value(st['sigma_frames_out_of_class'], '.2f')}")  # fmt: skip
    L += ["", "## Evidence", "", f"Ranking (first round; Delta BIC against the nuisance-only fit, plus the support of the candidate's own signature "
          f"(envelope, rest position, timing, how sharply a stop turns the motion, a hidden mode in the image), higher is better{smooth}):", "",
          "| effect | Delta BIC | signature | R2 | CV gain | physical | significant | coefficients (value +- s.e.) |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    if any(c.get("cv_gain_own") is not None for c in dg["ranking"]):
        L[-2:-2] = ["CV gain (own): where the signature alone passes, the candidate's own cross-validation, with the in-class "
                    "polynomials held at their fit on the whole take; it must not lose.", ""]  # fmt: skip
    for c in dg["ranking"]:
        coefs = "; ".join(f"{n} = {fmt_value(v['value'])} +- {fmt_value(v['se'], '.2g')}" for n, v in c["coefficients"].items())
        L.append(f"| {c['effect']} | {fmt_value(c['delta_bic'], '.1f')} | {fmt_value(c.get('signature_support', 0.0), '.1f')} | {fmt_value(c['r2'], '.2f')} | "
                 f"{_cv_cell(c)} | {fmt_value(c['physical'])} | {fmt_value(c['significant'])} | {coefs} |")  # fmt: skip
    if len(dg["ranking"]) > 1:
        a, b = dg["ranking"][0], dg["ranking"][1]
        L += ["", f"Margin of the first over the second: Delta BIC {fmt_value(a['delta_bic'] - b['delta_bic'], '.1f')}, CV gain {fmt_value(a['cv_gain'] - b['cv_gain'], '.2f')}."]
    why_not = not_significant_lines(dg)
    if why_not:
        L += ["", "Strong evidence that is not a finding, and the rule that stops it:", "", *why_not]
    ev = dg["evidence"]
    L += ["", "Signatures (most visible latent direction):", ""]
    env = ev.get("envelope", {})
    if env.get("best"):
        ratios = ", ".join(f"{k} {fmt_value(v, '.2f')}" for k, v in (env.get("sse_ratio_to_best") or {}).items())
        sup = env.get("support") or {}
        over = f"; evidence over exponential: linear {fmt_value(sup['linear'], '.1f')}, hyperbolic {fmt_value(sup['hyperbolic'], '.1f')}" if sup else ""
        L.append(f"- envelope of the decay: best **{env['best']}** ({env['n_turning_points']} turning points; SSE / best: {ratios}{over})")
    rest = ev.get("rest") or {}
    if rest.get("at_rest"):
        L.append(f"- rest: the motion stops at t = {fmt_value(rest['rest_time_s'], '.2f')} s, {fmt_value(abs(rest['offset_over_noise']), '.1f')} chart-noise levels "
                 f"off the centre of its oscillation (evidence for dry friction {fmt_value(rest['support'], '.1f')}; a viscous decay rests at its centre)")  # fmt: skip
    elif rest:
        L.append("- rest: the motion does not come to rest in these frames")
    fr = ev.get("frequency", {})
    if "slope_amp2" in fr:
        L.append(f"- frequency vs amplitude^2: z = {fmt_value(fr['z_amp2'], '.1f')} (shift at the largest amplitude {fmt_pct(fr['relative_shift_at_max_amplitude'])}); "
                 f"vs time: z = {fmt_value(fr['z_time'], '.1f')} (change over the span {fmt_pct(fr['relative_change_over_span'])})")  # fmt: skip
    sp = ev.get("spectrum", {})
    if sp:
        L.append(f"- residual spectral peaks (Hz): {', '.join(fmt_value(f) for f in sp.get('residual_peaks_hz', [])) or 'none'}; "
                 f"away from the model's modes, the motion's frequency and their harmonics: {', '.join(fmt_value(f) for f in sp.get('unexplained_peaks_hz', [])) or 'none'}")  # fmt: skip
    asy = ev.get("asymmetry")
    if asy:
        L.append(f"- excursion asymmetry: {fmt_value(asy['ratio'], '.2f')} (1 = symmetric)")
    return L


def identifiability_section(rep: Mapping[str, Any]) -> list[str]:
    """What the recording determines and what recording would settle the rest (``report.json``'s ``identifiability``,
    :func:`~lagsplat.diagnose.identifiability.identifiability`); nothing where the report carries none (a chart that
    supports no diagnosis, a stopped run, a record written before it)."""
    recs = rep.get("identifiability")
    if not recs:
        return []
    takes = ((rep.get("diagnosis") or {}).get("settings") or {}).get("n_segments")
    what = f"{takes} take{'s' if takes != 1 else ''} of training frames" if isinstance(takes, int) else "the training frames"
    L = ["", "## What this recording can and cannot tell", "",
         f"Read off {what} (the evidence above; the lines on what tells the candidates apart give each signature):", ""]  # fmt: skip
    for r in recs:
        if r["determined"]:
            L.append(f"- **{r['quantity']}**: determined. {r['why'][:1].upper() + r['why'][1:]}.")
        else:
            L.append(f"- **{r['quantity']}**: not determined. {r['why'][:1].upper() + r['why'][1:]}. Would settle it: {r['settle_by']}.")
    return L


def _where_time(tl: Mapping[str, Any], rep: Mapping[str, Any]) -> list[str]:
    """The time aspect: flagged shares, medians and the worst windows (:class:`~lagsplat.diagnose.where_time.TimeLocalisation`)."""
    L: list[str] = []
    L.append(f"**Time** ({fmt_value(tl['duration_s'], '.1f')} s of {rep['frames']['diagnosis_split']} frames, {tl['rollout_horizon_frames']}-frame free rollouts): "
             f"rollout error above {rep['config']['where']['floor_factor']:g}x the AE floor on {fmt_pct(tl['share_flagged_rollout'])[1:]} of the frames, "
             f"one-step residual above {rep['config']['where']['floor_factor']:g}x the chart noise on {fmt_pct(tl['share_flagged_residual'])[1:]}, both on {fmt_pct(tl['share_flagged_both'])[1:]}; "
             f"median rollout error / floor {fmt_value(tl['median_rollout_over_floor'], '.2f')}, median residual z^2 {fmt_value(tl['median_residual_z2'], '.2f')}.")  # fmt: skip
    if tl["windows"]:
        L += ["", "| window (s) | frames | peak rollout error / floor | mean residual z^2 |", "|---|---|---|---|"]
        for win in tl["windows"][:8]:
            L.append(f"| {win['t_start_s']:.2f} - {win['t_end_s']:.2f} | {win['n_frames']} | {fmt_value(win['peak_rollout_over_floor'], '.1f')} | {fmt_value(win['mean_residual_z2'], '.1f')} |")
        if len(tl["windows"]) > 8:
            L.append(f"| ... {len(tl['windows']) - 8} more | | | |")
    else:
        L.append("No window where both exceed their floor.")
    return L


def _where_state(st: Mapping[str, Any]) -> list[str]:
    """The phase-portrait regions (:class:`~lagsplat.diagnose.where.StateLocalisation`)."""
    L: list[str] = []
    L += ["", f"**State** (phase portrait; most enriched: **{st['most_enriched'].replace('_', ' ')}**):", "",
          "| region | share of samples | share of residual | enrichment | mean z^2 |", "|---|---|---|---|---|"]  # fmt: skip
    for name, r in st["regions"].items():
        L.append(f"| {name.replace('_', ' ')} | {fmt_value(r['sample_share'], '.2f')} | {fmt_value(r['residual_share'], '.2f')} | {fmt_value(r['enrichment'], '.2f')} | {fmt_value(r['mean_z2'], '.2f')} |")
    return L


def _where_latent(lt: Mapping[str, Any]) -> list[str]:
    """The eigen-directions of ``G_bar`` (:class:`~lagsplat.diagnose.where.LatentLocalisation`)."""
    L: list[str] = []
    L += ["", "**Latent directions** (eigenvectors of G_bar, most visible first):", "",
          "| direction | eigenvalue | visibility share | residual share | residual share (G_bar-weighted) | residual / noise | rollout-gap share (G_bar-weighted) |",
          "|---|---|---|---|---|---|---|"]  # fmt: skip
    for k, r in enumerate(lt["directions"]):
        L.append(f"| e{k + 1} | {fmt_value(r['eigenvalue'])} | {fmt_value(r['visibility_share'], '.2f')} | {fmt_value(r['residual_share'], '.2f')} | "
                 f"{fmt_value(r['residual_share_G'], '.2f')} | {fmt_value(r['residual_over_noise'], '.2f')} | {fmt_value(r['rollout_share_G'], '.2f')} |")  # fmt: skip
    return L


def _where_image(im: Mapping[str, Any]) -> list[str]:
    """The image excess and the Gaussians it falls on (:class:`~lagsplat.diagnose.localise.ImageLocalisation`)."""
    L: list[str] = []
    L += ["", f"**Image** ({im['n_frames']} rendered rollout frames): rollout image error {fmt_value(im['eps_rollout'])} against the AE floor "
          f"{fmt_value(im['eps_ae'])} on the same frames (excess {fmt_pct(im['excess_over_ae'])}). The positive excess falls "
          f"{fmt_pct(im['share_moving_gaussians'])[1:]} on moving Gaussians ({im['n_moving']} of {im['n_gaussians']}; they carry "
          f"{fmt_pct(im['moving_coverage'])[1:]} of the rendered colour, enrichment {fmt_value(im['moving_enrichment'], '.1f')}x), "
          f"{fmt_pct(im['share_static_gaussians'])[1:]} on static ones and {fmt_pct(im['share_background'])[1:]} on the background; "
          f"hottest pixel (x, y) = {tuple(im['hottest_pixel_xy'])}.", "",
          "| Gaussian | share | position (px) | motion (px per unit q) |", "|---|---|---|---|"]  # fmt: skip
    for g in im["top_gaussians"][:8]:
        L.append(f"| #{g['index']} | {fmt_value(g['share'], '.3f')} | ({g['position_px'][0]:.1f}, {g['position_px'][1]:.1f}) | {fmt_value(g['motion_px'], '.2f')} |")
    return L


def where_section(rep: Mapping[str, Any]) -> list[str]:
    """Where the gap shows: time windows, phase-portrait regions, latent directions, image."""
    w = rep["where"]
    L: list[str] = ["", "## Where it shows", ""]
    if w.get("time"):
        L += _where_time(w["time"], rep)
    if w.get("state"):
        L += _where_state(w["state"])
    if w.get("latent"):
        L += _where_latent(w["latent"])
    if w.get("image"):
        L += _where_image(w["image"])
    for n in w.get("notes", []):
        L.append(f"- note: {n}")
    return L


def gap_section(rep: Mapping[str, Any]) -> list[str]:
    """The held-out gap before and after the refit, with the envelope and the chart-noise floor."""
    L: list[str] = []
    gap = rep["gap"]
    if gap.get("unavailable"):
        if rep.get("held_out"):
            return ["", "## Held-out gap", "", f"Not measured: {rep['held_out']} (the clip was identified on all its frames). "
                    "The diagnosis above reads the training frames only and stands without it."]  # fmt: skip
        return ["", "## Held-out gap", "", f"Not measured: {gap['unavailable']}. The diagnosis above reads the training frames only and stands without it."]
    fr_def = gap["definition"]["frames"]
    L += ["", "## Held-out gap", "", fr_def[:1].upper() + fr_def[1:] + ".", ""]
    cols = ["before"] + (["after"] if gap["after"] else []) + (["control"] if gap["control"] else [])
    head = {"before": "before (identified model)", "after": "after (refit with the effect)", "control": "control (same refit, no term)"}
    L += ["| metric | " + " | ".join(head[c] for c in cols) + (" | reduction | reduction vs control |" if gap["after"] else " |"),
          "|---" * (len(cols) + 1 + (2 if gap["after"] else 0)) + "|"]  # fmt: skip
    for k in GAP_METRICS:
        row = f"| {GAP_LABELS[k]} | " + " | ".join(fmt_value(gap[c].get(k), ".4g") for c in cols)
        if gap["after"]:
            row += f" | {fmt_pct(gap['reduction'].get(k))} | {fmt_pct((gap['reduction_vs_control'] or {}).get(k))}"
        L.append(row + " |")
    env_b = gap["before"].get("envelope") or {}
    if env_b.get("form"):
        dec = env_b["decay_encoded"]
        change = f"gains {fmt_pct(-dec)[1:]}" if dec < 0 else f"loses {fmt_pct(dec)[1:]}" + (" (it comes to rest)" if dec >= 0.995 else "")
        L.append(f"\nEnvelope: {env_b['form']} fit; the encoded held-out video {change} of its amplitude over the segment"
                 + ("" if env_b.get("reliable") else " (too little decay for a reliable relative error)") + ".")  # fmt: skip
    fl = gap["before"].get("floor") or {}
    if fl.get("eps_q") is not None:
        L.append(f"\nChart-noise floor (lagsplat.diagnose.refit.noise_floor: the identified model's own motion plus the chart's noise, "
                 f"{fl['n_draws']} draws): eps_q {fmt_value(fl['eps_q'], '.4g')} ± {fmt_value(fl['eps_q_sd'], '.2g')}, eps_freq {fmt_value(fl['eps_freq'], '.3g')}; "
                 "what no model can remove from this chart.")  # fmt: skip
    if "before_matches_metrics_json" in gap:
        L.append(f"\nThe 'before' eps_q {'matches' if gap['before_matches_metrics_json'] else 'differs from'} metrics.json ({fmt_value(gap['metrics_json_eps_q'], '.4g')}).")
    return L


def _figure_reading(key: str, rep: Mapping[str, Any]) -> str:
    """The sentence read off a figure, after its link (the backbone's; nothing for the others)."""
    bb = rep.get("backbone") or {}
    if key != "backbone" or not bb.get("reading"):
        return ""
    caveat = " (on a chart that fails its checks: a description, not a finding)" if rep.get("verdict") == "cannot_diagnose" else ""
    errors = "".join(f" The {k} could not be rolled out ({m['error']})." for k, m in (bb.get("models") or {}).items() if "error" in m)
    note = f" Note: {bb['note']}." if bb.get("note") else ""
    return f": frequency and damping ratio against amplitude{caveat}. {bb['reading']}{errors}{note}"


def refit_section(rep: Mapping[str, Any]) -> list[str]:
    """The refit (or why none), the figures and which frames were read."""
    L: list[str] = []
    rf = rep["refit"]
    L += ["", "## Refit", ""]
    if not rf.get("done"):
        L.append(rf.get("reason", "no refit"))
        for k, v in (rf.get("spec", {}) or {}).get("not_refit", {}).items():
            L.append(f"- {k}: {v}")
    else:
        cfg = rep["config"]["refit"]
        how = ("scratch start: a fresh Stage 2 with the term, its configured epochs" if cfg["init"] == "scratch"
               else f"fitted start, {cfg['epochs']} epochs, energy gauge x{cfg['floor_scale']:g}")  # fmt: skip
        L.append(f"Stage 2 refit ({how}; model selection on training rollouts), "
                 f"selected epoch {rf['selected_epoch']}, training-rollout NRMSE {fmt_value(rf['selected_train_nrmse'], '.4g')} (control {fmt_value(rf['control_selected_train_nrmse'], '.4g')}).")  # fmt: skip
        for t0, t1 in zip(rf["spec"]["init_terms"], rf["fitted_terms"]):
            vals = ", ".join(f"{k} {fmt_value(t0[k])} -> {fmt_value(t1[k])}" for k in t1 if k not in ("class", "direction") and isinstance(t1[k], (int, float)))
            L.append(f"- {t1['class']} along {[round(v, 3) for v in t1['direction']]}: {vals} (start -> refit)")
        if rf["spec"]["delay_s"]:
            L.append(f"- input read {rf['spec']['delay_s']:.3f} s late")
        for k, v in rf["spec"].get("not_refit", {}).items():
            L.append(f"- {k} not refit: {v}")
        ec = rf["energy_check"]
        L.append(f"- energy bound (App. A.2): {'holds' if ec['holds'] else 'VIOLATED'}; max power of the dissipative terms "
                 f"{fmt_value(ec['max_dissipative_power'], '.2g')}, max energy rise along free rollouts {fmt_value(ec['max_energy_rise'], '.2g')}")  # fmt: skip
    if rep.get("figures"):
        L += ["", "## Figures", ""] + [f"- {k}: [{v}]({v})" + _figure_reading(k, rep) for k, v in rep["figures"].items()]
    bb = rep.get("backbone") or {}
    if bb and not bb.get("done"):
        L += (["", "## Figures", ""] if not rep.get("figures") else []) + [f"- backbone: not drawn: {bb.get('reason')}."]
    fr_ = rep["frames"]
    L += ["", f"Frames: diagnosis and localisation on {fr_['n_diagnosis_frames']} {fr_['diagnosis_split']} frames; "
          f"{fr_['n_held_out_frames']} held-out frames used for {fr_['held_out_used_for']}.", ""]  # fmt: skip
    return L


def render_markdown(rep: Mapping[str, Any]) -> str:
    """``report.md`` from the report mapping (the content of ``report.json``)."""
    lines: list[str] = []
    for section in (verdict_section, quantities_section, evidence_section, identifiability_section, where_section, gap_section, refit_section):
        lines += section(rep)
    return "\n".join(lines)

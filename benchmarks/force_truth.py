"""Forces against a known truth: the synthetic pendulum pushed at a known point.

The model is one trained on the checkered pendulum's *free* motion
(``results/pendulum_force``: ``snakemake -c2 results/pendulum_force/forces.json``;
the toy's works too). A static force ``F = (Fx, Fy)``
(image axes, ``y`` down) applied at radius ``r`` on the rod of the pendulum
``lagsplat.synth.pendulum`` (pivot at ``(W/2, PIVOT_Y H)``, bob at
``ROD_LENGTH H``) holds it at the angle ``theta`` that balances gravity:

    I w0^2 sin(theta) = r (Fx cos(theta) - Fy sin(theta)),

with ``I w0^2`` set to 1 (the force unit). The application point then moves
by ``r (sin theta, cos theta - 1)`` pixels. The model predicts the same
displacement as ``p(q_eq) - p(q_rest)`` with ``q_eq`` the loaded equilibrium
under ``kappa sum_i w_i J_i^T F`` (paper Eq. 9). ``kappa`` is calibrated on the
first force only; the others are compared by direction (degrees) and
magnitude (%) of the displacement.

Two read-outs of the model's displacement, each with its own ``kappa``
calibrated on the first force:

* **application point**: ``p(q) = sum_i w_i mu_i(q)`` of the frozen selection
  (paper §3.4). Its primitives move on straight lines (constant ``J_i``), so
  against the true arc it carries the chord-vs-tangent tilt of about
  ``theta / 2`` on top of the decoder's own errors;
* **chart read-out**: the rigid-body angle the model's equilibrium *state*
  shows, ``theta_m = theta(q_eq)`` with ``theta(q)`` the cubic fitted to the
  encoded training frames against their known angle (the encoder as the
  measuring instrument, the same one that reads a real video), and the point
  at radius ``r`` moved by ``r (sin theta_m, cos theta_m - 1)``. This compares
  the loaded equilibrium state with the true one; its direction error is
  the sign and half the angle error.

The brush and its front-surface threshold are the ones the pipeline used
(``sigma_px`` and ``min_transmittance`` of the folder's ``forces.json``,
i.e. ``forces.sigma`` and ``forces.min_transmittance`` of the system's
config), unless ``--sigma`` / ``--min-transmittance`` are given. Each row
also shows Eq. 9's own floor (:func:`constant_j_angle`) and how far the
brushed material moved in the training clip, rms px, as the model sees it
(:meth:`~lagsplat.forces.transport.ForceTransport.observed_motion` on the encoded
training states) and in truth. A force is scored only where the model saw
its material move by at least ``--min-motion`` px (default 1): the decoder
learns ``J_i`` from the video's motion, so below a pixel the force is
extrapolated. Forces below it are printed and summarised apart (the
counter-arm, 4.5 px above the pivot). The summary is printed over the scored
forces and over those Eq. 9 carries (floor below half the magnitude
tolerance: all but the vertical pull).

With several trained folders (other seeds), a last table gives per force the
number of models within tolerance and the spread of its magnitude error: a
force that fails on every training (a bias of the read-out) shows apart from
one that fails on some (the decoder's Jacobians varying between trainings).

    python benchmarks/force_truth.py [--results results/pendulum_force [more trained folders ...]] [--sigma 1.5] [--min-transmittance 0.5]

Prints the tables and writes them to ``results/benchmarks/force_truth.md``
(``--report PATH``, ``--no-report``); no assertion (scores, not tests).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import NamedTuple

import lagsplat  # noqa: F401  (sets the OpenMP wait policy before torch)
import numpy as np
import torch
from scipy.optimize import brentq

from lagsplat.artifacts import Artifacts  # noqa: E402
from lagsplat.io.clip import TRAIN
from lagsplat.forces.transport import ForceTransport, calibrate_kappa
from lagsplat.forces.checks import ForceCheckConfig
from lagsplat.synth.pendulum import PIVOT_Y, ROD_LENGTH

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Report, add_report_options  # this script's folder


def true_angle(F: np.ndarray, r: float) -> float:
    """Static angle (rad) under force ``F`` (force units, ``I w0^2 = 1``) at radius ``r`` (units of the rod)."""
    g = lambda th: math.sin(th) - r * (F[0] * math.cos(th) - F[1] * math.sin(th))  # noqa: E731
    return brentq(g, -math.pi / 2 + 1e-9, math.pi / 2 - 1e-9)


class Row(NamedTuple):
    """One force of the table: its setup, truth, and each read-out's displacement (px) and errors (deg, %)."""

    k: int
    r: float
    F: np.ndarray
    th_deg: float
    d_true: np.ndarray
    dp: np.ndarray
    dir_p: float
    mag_p: float
    dc: np.ndarray
    dir_c: float
    mag_c: float
    floor: float
    seen: float
    seen_true: float


def arc_displacement(theta: float, r: float, L_px: float) -> np.ndarray:
    """Displacement (px, image axes) of the rod point at radius ``r`` (units of the rod ``L_px``) swung from rest to ``theta`` (rad)."""
    return r * L_px * np.array([math.sin(theta), math.cos(theta) - 1.0])


def true_motion(theta: np.ndarray, r: float, L_px: float) -> float:
    """Rms displacement (px) about its mean of the rod point at radius ``r`` over the angles ``theta [T]`` (rad)."""
    p = r * L_px * np.stack([np.sin(theta), np.cos(theta)], 1)
    return float(np.sqrt(((p - p.mean(0)) ** 2).sum(1).mean()))


def constant_j_angle(F: np.ndarray, r: float, kappa: float) -> float:
    """Static angle (rad) of the exact *constant-Jacobian* pendulum: Eq. 9's own error, free of any learning.

    The true potential ``1 - cos(theta)`` and the true Jacobian of the point at
    radius ``r``, but frozen at rest, ``r (1, 0)`` (paper Eq. 9: constant
    ``J_i``), so the generalized force is ``kappa r Fx`` whatever the angle and
    ``sin(theta) = kappa r Fx``. The vertical component drops out: what this
    angle misses against :func:`true_angle` is built into the method.
    """
    return math.asin(max(-1.0, min(1.0, kappa * r * F[0])))


def chart_readout(chart, clip, degree: int = 3) -> tuple[np.poly1d, float]:
    """Cubic ``theta(q)`` (rad) fitted to the encoded training frames and their true angles; its rms residual (deg)."""
    train = clip.split == TRAIN
    q = np.asarray(chart.q[train, 0], float)
    th = np.asarray(clip.meta["theta"], float)[train]
    poly = np.poly1d(np.polyfit(q, th, degree))
    return poly, float(np.degrees(np.sqrt(np.mean((poly(q) - th) ** 2))))


def score(d_true: np.ndarray, d_pred: np.ndarray) -> tuple[float, float]:
    """Direction error (deg, signed) and magnitude error (%) of a predicted displacement."""
    ang = math.degrees(math.atan2(d_true[0] * d_pred[1] - d_true[1] * d_pred[0], float(d_true @ d_pred)))
    return ang, 100.0 * (np.linalg.norm(d_pred) / np.linalg.norm(d_true) - 1.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--results", nargs="+", default=["results/pendulum_force"],
        help="folder(s) of a trained pendulum system (pendulum_force or toy); several (e.g. trainings with other seeds): "
        "one table each, then one summary line each",
    )
    ap.add_argument("--brush", default="visible", choices=["visible", "paper"], help="brush weighting (lagsplat.forces.transport)")
    ap.add_argument(
        "--sigma", type=float, default=None,
        help="brush radius, pixels (default: the folder's forces.json, i.e. the system's forces.sigma; the visible brush "
        "reaches 2 sigma, so at 1.5 px a click 4.5 px above the pivot also touches the static pivot disc)",
    )
    ap.add_argument(
        "--min-transmittance", type=float, default=None,
        help="visible brush: a primitive counts only where at least this share of the light reaches it, the surface the "
        "click meets (lagsplat.forces.transport; default: the folder's forces.json, i.e. the system's forces.min_transmittance)",
    )
    ap.add_argument(
        "--min-motion", type=float, default=1.0,
        help="score a force only where the model saw the brushed material move by at least this much (rms px) in "
        "the training clip (ForceTransport.observed_motion); the others are printed apart",
    )
    ap.add_argument("--max-deg", type=float, default=5.0, help="direction tolerance counted in the summary")
    ap.add_argument("--max-pct", type=float, default=10.0, help="magnitude tolerance counted in the summary")
    add_report_options(ap, "force_truth")
    args = ap.parse_args()
    rep = Report("Forces against a known truth (checkered pendulum)", args.report, __file__)
    summaries = [(d, force_truth(Path(d), args, rep)) for d in args.results]
    if len(summaries) > 1:
        lines = [
            (
                f"chart read-out, scored forces (seen moving >= {args.min_motion:g} px) within tolerance (all | those Eq. 9 carries), "
                "largest magnitude error; forces not scored:"
            )
        ]
        for d, rows in summaries:
            test, unseen = scored(rows[1:], args)
            carried = carried_forces(test, args)
            lines.append(
                f"  {d}: {n_within(test, args)} of {len(test)} | {n_within(carried, args)} of {len(carried)}, "
                f"{max(abs(r.mag_c) for r in test):.1f} %; " + (", ".join(f"#{r.k} {r.mag_c:+.1f} %" for r in unseen) or "none")
            )
        print()
        rep.text(*lines)
        per_force(args, [rows for _, rows in summaries], rep)
    rep.write()


def brush_settings(d: Path, args: argparse.Namespace) -> tuple[float, float, str]:
    """Brush radius (px), front-surface threshold and where they come from.

    The command line's, else the folder's ``forces.json`` (what the force
    checks of ``python -m lagsplat forces`` used), else the defaults of
    :class:`~lagsplat.forces.checks.ForceCheckConfig`.
    """
    cfg = ForceCheckConfig()
    sigma, tau, source = cfg.sigma, cfg.min_transmittance, "defaults"
    if (d / "forces.json").exists():
        used = json.loads((d / "forces.json").read_text())
        sigma, tau, source = float(used.get("sigma_px", sigma)), float(used.get("min_transmittance", tau)), "forces.json"
    if args.sigma is not None or args.min_transmittance is not None:
        source = "command line" if source == "defaults" else f"command line, else {source}"
    return (sigma if args.sigma is None else args.sigma), (tau if args.min_transmittance is None else args.min_transmittance), source


def is_scored(r: Row, args: argparse.Namespace) -> bool:
    """Whether the model saw the force's material move by at least ``--min-motion`` px in training."""
    return r.seen >= args.min_motion


def scored(test: list[Row], args: argparse.Namespace) -> tuple[list[Row], list[Row]]:
    """The forces :func:`is_scored` keeps, and the others."""
    return [r for r in test if is_scored(r, args)], [r for r in test if not is_scored(r, args)]


def within(r: Row, args: argparse.Namespace, ia: str = "dir_c", im: str = "mag_c") -> bool:
    """Whether a force's read-out (fields ``ia`` direction, ``im`` magnitude; default: chart) is within both tolerances."""
    return abs(getattr(r, ia)) <= args.max_deg and abs(getattr(r, im)) <= args.max_pct


def n_within(sub: list[Row], args: argparse.Namespace, ia: str = "dir_c", im: str = "mag_c") -> int:
    """Forces of ``sub`` within both tolerances (:func:`within`)."""
    return sum(within(r, args, ia, im) for r in sub)


def carried_forces(test: list[Row], args: argparse.Namespace) -> list[Row]:
    """The forces Eq. 9 itself carries: its floor leaves at least half the magnitude tolerance to the model."""
    return [r for r in test if abs(r.floor) < 0.5 * args.max_pct]


def per_force(args: argparse.Namespace, runs: list[list[Row]], rep: Report) -> None:
    """Per force, over the trained models: how many are within tolerance, and the spread of the magnitude error (chart)."""
    print()
    rep.text(f"per force over the {len(runs)} models (chart read-out): within {args.max_deg:g} deg and {args.max_pct:g} %, magnitude error (%)")
    table = [
        (
            "| # | radius | force (Fx, Fy) | Eq. 9 floor (%) | seen moving, rms px (model: min-max) | scored on | models within "
            "| min | median | max | max abs dir err (deg) |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for rows in zip(*runs):
        r0, mags, seen = rows[0], np.array([r.mag_c for r in rows]), np.array([r.seen for r in rows])
        table.append(
            f"| {r0.k} | {r0.r:.2f} | ({r0.F[0]:+.3f}, {r0.F[1]:+.3f}) | {r0.floor:+.1f} | {seen.min():.2f}-{seen.max():.2f} | "
            f"{sum(is_scored(r, args) for r in rows)} | {sum(within(r, args) for r in rows)} of {len(rows)} | "
            f"{mags.min():+.1f} | {np.median(mags):+.1f} | {mags.max():+.1f} | {max(abs(r.dir_c) for r in rows):.2f} |"
        )
    rep.block("\n".join(table))


def force_truth(d: Path, args: argparse.Namespace, rep: Report) -> list[Row]:
    """Print the table and summary of one trained model (and record them in ``rep``); return its rows (the first is the calibration)."""
    a = Artifacts.at(d)
    ae, chart, clip = a.load_stage1(), a.load_chart(), a.load_clip()
    model, _ = a.load_stage2()
    sigma, tau, source = brush_settings(d, args)
    tr = ForceTransport.from_autoencoder(ae, chart, brush=args.brush, min_transmittance=tau)
    theta_of_q, fit_rms_deg = chart_readout(chart, clip)
    H, W = ae.height, ae.width
    L_px = ROD_LENGTH * H
    pivot = np.array([W / 2.0, PIVOT_Y * H])
    q0 = model.q_rest.detach()[None]
    th0 = float(theta_of_q(float(q0[0, 0])))
    train = clip.split == TRAIN
    q_train = torch.as_tensor(np.asarray(chart.q)[train], dtype=torch.float32)
    theta_train = np.asarray(clip.meta["theta"], float)[train]

    # (radius as a fraction of the rod, force); the first row calibrates kappa.
    # Negative radii lie on the counter-arm above the pivot (pendulum_force).
    # The last row pulls down as hard as it pushes sideways: a vertical force
    # changes the pendulum's effective stiffness (its torque is -r Fy sin theta,
    # second order in the state), which constant Jacobians (Eq. 9) cannot carry.
    cases = [
        (1.0, (0.06, 0.0)),
        (1.0, (0.12, 0.0)),
        (1.0, (-0.09, 0.0)),
        (1.0, (0.05, 0.02)),
        (1.0, (-0.10, -0.03)),
        (1.0, (0.04, 0.0)),
        (0.75, (0.12, 0.0)),
        (0.75, (-0.10, 0.03)),
        (0.5, (0.16, 0.0)),
        (0.5, (-0.20, -0.05)),
        (-0.12, (0.60, 0.0)),
        (1.0, (0.08, 0.08)),
    ]

    def disp_point(q_eq: torch.Tensor, sel) -> np.ndarray:
        return (tr.application_point(q_eq, sel) - tr.application_point(q0, sel))[0].detach().numpy().astype(float)

    def disp_chart(q_eq: torch.Tensor, r: float) -> np.ndarray:
        return arc_displacement(float(theta_of_q(float(q_eq[0, 0]))) - th0, r, L_px)

    setups = []
    for r, F in cases:
        F = np.asarray(F, float)
        x = torch.as_tensor((pivot + [0.0, r * L_px])[None], dtype=torch.float32)
        sel = tr.select(q0, x, sigma)
        th = true_angle(F, r)
        d_true = arc_displacement(th, r, L_px)
        seen = float(tr.observed_motion(sel, q_train)[0])
        seen_true = true_motion(theta_train, r, L_px)
        setups.append((r, F, sel, th, d_true, tr.pullback(sel, torch.as_tensor(F[None], dtype=torch.float32)), seen, seen_true))

    def equilibrium(kappa: float, f_lat: torch.Tensor) -> torch.Tensor:
        return model.loaded_equilibrium(kappa * f_lat, q0=q0)

    # kappa of each read-out from the first force
    r0, F0, sel0, th_cal, d0 = setups[0][:5]
    calib = (model, tr, sel0, torch.as_tensor(F0[None], dtype=torch.float32), float(np.linalg.norm(d0)))
    kappa_point = calibrate_kappa(*calib, q_rest=q0)
    kappa_chart = calibrate_kappa(*calib, q_rest=q0, readout=lambda q_eq: float(np.linalg.norm(disp_chart(q_eq, r0))))

    # Eq. 9's own floor: the exact pendulum with its Jacobians frozen at rest, kappa from the same first force
    kappa_exact = math.sin(th_cal) / (r0 * F0[0])

    rows = []
    for k, (r, F, sel, th, d_true, f_lat, seen, seen_true) in enumerate(setups):
        dp = disp_point(equilibrium(kappa_point, f_lat), sel)
        dc = disp_chart(equilibrium(kappa_chart, f_lat), r)
        floor = score(d_true, arc_displacement(constant_j_angle(F, r, kappa_exact), r, L_px))[1]
        rows.append(Row(k, r, F, math.degrees(th), d_true, dp, *score(d_true, dp), dc, *score(d_true, dc), floor, seen, seen_true))

    rep.text(
        f"pendulum model: {d} ({W}x{H} px, rod {L_px:.1f} px), brush {args.brush} sigma {sigma:g} px"
        + (f" min transmittance {tr.min_transmittance:g}" if args.brush == "visible" else "")
        + f" ({source}); "
        + f"kappa {kappa_point:.4g} (application point), {kappa_chart:.4g} (chart read-out); "
        f"chart read-out theta(q): cubic on {int(train.sum())} training frames, rms {fit_rms_deg:.3f} deg"
    )
    table = [
        (
            "| # | radius | force (Fx, Fy) | true angle (deg) | true disp (px) | Eq. 9 floor: mag err (%) "
            "| application point disp (px) | dir err (deg) | mag err (%) "
            "| chart read-out disp (px) | dir err (deg) | mag err (%) | seen moving in training, rms px: model | truth |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        k, r, F, th, dt_, dp, ang_p, mag_p, dc, ang_c, mag_c, floor, seen, seen_true = row
        tag = " (calibration)" if k == 0 else ("" if is_scored(row, args) else " (not scored)")
        table.append(
            f"| {k}{tag} | {r:.2f} | ({F[0]:+.3f}, {F[1]:+.3f}) | {th:+.2f} | ({dt_[0]:+.2f}, {dt_[1]:+.2f}) | {floor:+.1f} | "
            f"({dp[0]:+.2f}, {dp[1]:+.2f}) | {ang_p:+.2f} | {mag_p:+.1f} | ({dc[0]:+.2f}, {dc[1]:+.2f}) | {ang_c:+.2f} | {mag_c:+.1f} | "
            f"{seen:.2f} | {seen_true:.2f} |"
        )
    rep.block("\n".join(table))
    test, unseen = scored(rows[1:], args)
    carried = carried_forces(test, args)

    print()
    summary = []
    for name, ia, im in (("application point", "dir_p", "mag_p"), ("chart read-out", "dir_c", "mag_c")):
        for label, sub in (("", test), (f" [the {len(carried)} Eq. 9 carries: floor below {0.5 * args.max_pct:g} %]", carried)):
            summary.append(
                f"{name}{label}: over {len(sub)} forces after calibration, max |direction error| {max(abs(getattr(r, ia)) for r in sub):.2f} deg, "
                f"max |magnitude error| {max(abs(getattr(r, im)) for r in sub):.1f} %, median |magnitude error| {np.median([abs(getattr(r, im)) for r in sub]):.1f} %; "
                f"{n_within(sub, args, ia, im)} of {len(sub)} within {args.max_deg:g} deg and {args.max_pct:g} %"
            )
    rep.text(*summary)
    if unseen:
        rep.text(
            f"not scored, material seen moving below {args.min_motion:g} px rms in training (chart read-out): "
            + "; ".join(f"#{r.k} at r {r.r:+.2f}: {r.seen:.2f} px, dir {r.dir_c:+.2f} deg, mag {r.mag_c:+.1f} %" for r in unseen)
        )
    return rows


if __name__ == "__main__":
    main()

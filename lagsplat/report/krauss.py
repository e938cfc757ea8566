"""The soft-robot table (paper Table 4): published rows beside ours, never recomputed.

Rows come from two places only:

* the versioned CSV of published figures, ``lagsplat/report/data/krauss_published.csv``
  (one row per method and configuration, with a ``source`` column citing the
  paper table or section it is copied from; an empty cell is a number the
  source does not give, and stays empty);
* the ``metrics.json`` written by ``python -m lagsplat evaluate`` under the
  published protocol (:mod:`lagsplat.evaluate.krauss`): the one- and
  two-segment runs and the two-segment inertia ablation (paper §4.4). A run
  whose ``metrics.json`` is missing gives no row: nothing is filled in.

Outputs, written atomically side by side: ``krauss.tex`` (the layout of paper
Table 4: Method, Dyn., d, AE (1e-5), MSE (1e-3), eps_freq (%), Ext. force,
grouped by configuration, plus an inertia-ablation block), ``krauss.csv``
(every row with its data kind, origin and source, and for our rows the
frequencies behind eps_freq and, on the surrogate, the errors against the
simulator) and ``krauss.md``.

Rows on the simulated surrogate (``metrics.json`` with ``"data":
"surrogate"``) are marked with a dagger and a note, carry ``data =
surrogate`` in the CSV, and are never bolded against the published rows.
"""

from __future__ import annotations

import json
import math
from importlib import resources
from pathlib import Path
from typing import Any, Iterable

import pandas as pd

from lagsplat.io.atomic import atomic_write
from lagsplat.report.tables import write_tex_csv

__all__ = ["BLOCKS", "COLUMNS", "load_published", "our_row", "krauss_rows", "krauss_table"]

#: Row groups, in table order: (block key, title in the table).
BLOCKS = (
    ("one_segment", r"\emph{One segment}, two chambers"),
    ("two_segments", r"\emph{Two segments}, four chambers"),
    ("inertia_ablation", r"\emph{Two segments, inertia} (\S4.4, same frozen chart)"),
)
#: Columns of the published CSV (and the first columns of ``krauss.csv``).
COLUMNS = ("block", "method", "dynamics", "d", "ae_1e-5", "mse_1e-3", "eps_freq_pct", "ext_force", "data", "source")
_NUMERIC = ("d", "ae_1e-5", "mse_1e-3", "eps_freq_pct")
_FORCE_TEX = {"none": r"$\times$", "latent": r"${\sim}$", "image_points": r"$({\checkmark})$", "image": r"$\checkmark$"}
_FORCE_MD = {"none": "×", "latent": "~", "image_points": "(✓)", "image": "✓"}
_MASS_LABEL = {"learned": "learned M", "decoder": "decoder-induced M", "constant": "constant M", "scalar": "scalar M"}
_DATA = ("real", "surrogate")


def load_published(path: str | Path | None = None) -> pd.DataFrame:
    """Read the published-figures CSV (``#`` lines are comments).

    Args:
        path: a CSV with :data:`COLUMNS`; default the packaged
            ``lagsplat/report/data/krauss_published.csv``.

    Returns:
        One row per published figure set, with an added ``origin = "published"`` column.

    Raises:
        ValueError: naming the file, for a missing column, an unknown block,
            ``ext_force`` or ``data`` value, a non-numeric number, or a row
            without a ``source``.
    """
    if path is None:
        ref = resources.files("lagsplat.report").joinpath("data/krauss_published.csv")
        with resources.as_file(ref) as p:
            return load_published(p)
    path = Path(path)
    df = pd.read_csv(path, comment="#", dtype={"source": str})
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; expected {list(COLUMNS)}")
    blocks = {b for b, _ in BLOCKS}
    for col, allowed in (("block", blocks), ("ext_force", set(_FORCE_TEX)), ("data", set(_DATA))):
        bad = sorted(set(df[col].astype(str)) - allowed)
        if bad:
            raise ValueError(f"{path}: column {col!r} has unknown value(s) {bad}; allowed: {sorted(allowed)}")
    for col in _NUMERIC:
        try:
            df[col] = pd.to_numeric(df[col])
        except (TypeError, ValueError):
            raise ValueError(f"{path}: column {col!r} must hold numbers (empty when not published)") from None
    if df["source"].isna().any() or (df["source"].astype(str).str.strip() == "").any():
        raise ValueError(f"{path}: every row needs a source (rows {list(df.index[df['source'].isna()])})")
    df = df[list(COLUMNS)].copy()
    df["origin"] = "published"
    return df


def _value(v: dict[str, Any], key: str, scale: float = 1.0) -> float:
    x = v.get(key)
    return float("nan") if x is None else scale * float(x)


def our_row(metrics_path: str | Path, block: str, label: str | None = None) -> dict[str, Any] | None:
    """One table row from a ``metrics.json`` of the published protocol, or ``None`` if the file is missing.

    Args:
        metrics_path: ``results/<system>[/variants/<v>]/metrics.json``.
        block: the :data:`BLOCKS` key the row goes in.
        label: method name; default ``"LaGSplat (this run)"``, or the inertia
            form of a variant (``"LaGSplat, decoder-induced M (this run)"``).

    Returns:
        The row (keys :data:`COLUMNS` plus ``origin = "this run"`` and the
        extra columns ``eps_q``, ``f_enc_hz``, ``f_sim_hz``, ``mse_sem_1e-3``,
        ``n_freq_windows`` and, on the surrogate, ``f_truth_hz``,
        ``eps_freq_truth_pct``, ``eps_freq_enc_truth_pct``), or ``None``.

    Raises:
        ValueError: naming the file, if it is not JSON or was not written by
            the published protocol (no ``mse_0p5s`` metric).
    """
    p = Path(metrics_path)
    if not p.is_file():
        return None
    try:
        m = json.loads(p.read_text())
        v = {k: e["value"] for k, e in m["metrics"].items()}
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{p}: not a lagsplat metrics.json ({exc})") from None
    if "mse_0p5s" not in v:
        raise ValueError(f"{p}: no 'mse_0p5s' metric; evaluate this run with system.protocol=krauss (lagsplat.evaluate.krauss)")
    data = m.get("data", "real")
    if label is None:
        mass = (m.get("stage2") or {}).get("mass", "")
        label = f"LaGSplat, {_MASS_LABEL.get(mass, mass)} (this run)" if m.get("variant") else "LaGSplat (this run)"
    row: dict[str, Any] = {
        "block": block,
        "method": label,
        "dynamics": "nonlin.",
        "d": m.get("d"),
        "ae_1e-5": _value(v, "ae_floor", 1e5),
        "mse_1e-3": _value(v, "mse_0p5s", 1e3),
        "eps_freq_pct": _value(v, "eps_freq", 100.0),
        "ext_force": "image",
        "data": data,
        "source": f"this run: {p} (system {m.get('system')}" + (f", variant {m['variant']}" if m.get("variant") else "") + ", lagsplat.evaluate.krauss)",
        "origin": "this run",
        "mse_sem_1e-3": _value(v, "mse_0p5s_sem", 1e3),
        "eps_q": _value(v, "eps_q"),
        "f_enc_hz": _value(v, "f_enc_hz"),
        "f_sim_hz": _value(v, "f_sim_hz"),
        "n_freq_windows": sum(1 for w in (v.get("freq_windows") or []) if w.get("status") == "ok"),
    }
    if "f_truth_hz" in v:
        row["f_truth_hz"] = _value(v, "f_truth_hz")
        row["eps_freq_truth_pct"] = _value(v, "eps_freq_truth", 100.0)
        row["eps_freq_enc_truth_pct"] = _value(v, "eps_freq_enc_truth", 100.0)
    return row


def median_row(paths: list[str | Path], block: str) -> dict[str, Any] | None:
    """One row from several runs of one variant (``<variant>@seed<k>``, Stage-2 seeds on the
    frozen chart): each number the median over the runs that exist (paper §4.1 reports the
    median over seeds), ``seeds`` how many there were; ``None`` if none exists.

    Raises:
        ValueError: see :func:`our_row`.
    """
    rows = [r for r in (our_row(p, block) for p in paths) if r is not None]
    if not rows:
        return None
    df = pd.DataFrame(rows)
    out = dict(rows[0])
    for col in df.columns:
        if col not in ("d", "block") and pd.api.types.is_numeric_dtype(df[col]):
            out[col] = float(df[col].median())
    n = len(rows)
    out["method"] = out["method"].replace(" (this run)", f", median of {n} seeds (this run)") if n > 1 else out["method"]
    kept = [Path(p) for p in paths if Path(p).is_file()]
    out["source"] = f"this run: median over {n} seeds ({', '.join(p.parent.name for p in kept)} under {kept[0].parent.parent})" if n > 1 else out["source"]
    out["seeds"] = n
    return out


def krauss_rows(
    one_segment: str | Path | None,
    two_segments: str | Path | None,
    ablation: Iterable[str | Path] = (),
    published: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """All rows of the table, in table order: per block, the published rows then ours.

    Args:
        one_segment, two_segments: ``metrics.json`` of our runs (``None`` or a
            missing file: no row).
        ablation: ``metrics.json`` of the two-segment inertia variants; an entry
            that is a list of them (the variant's Stage-2 seeds) gives one row,
            their median (:func:`median_row`).
        published: the published rows (default :func:`load_published`).

    Raises:
        ValueError: see :func:`load_published` and :func:`our_row`.
    """
    pub = load_published() if published is None else published
    ours = [our_row(one_segment, "one_segment") if one_segment else None, our_row(two_segments, "two_segments") if two_segments else None]
    ours += [median_row(list(a), "inertia_ablation") if isinstance(a, (list, tuple)) else our_row(a, "inertia_ablation") for a in ablation]
    df_ours = pd.DataFrame([r for r in ours if r is not None])
    parts = []
    for b, _ in BLOCKS:
        parts.append(pub[pub["block"] == b])
        if len(df_ours):
            parts.append(df_ours[df_ours["block"] == b])
    parts = [p for p in parts if len(p)]
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=[*COLUMNS, "origin"])


def _num(x: Any, fmt: str) -> str:
    try:
        f = float(x)
    except (TypeError, ValueError):
        return "--"
    return "--" if not math.isfinite(f) else format(f, fmt)


def _tex_method(name: str) -> str:
    s = str(name).replace("&", r"\&").replace("%", r"\%").replace("_", r"\_")
    s = s.replace(" + ", r"\,+\,").replace("LaGSplat", r"\textbf{LaGSplat}")
    return s.replace(" M ", " $M$ ").replace(" M)", " $M$)")


_FMT = {"ae_1e-5": ".3g", "mse_1e-3": ".3g", "eps_freq_pct": ".1f"}


def _best(df: pd.DataFrame) -> dict[tuple[str, str], float]:
    """Smallest value per (block, column) among real-data rows of the two configuration blocks (bolded)."""
    best = {}
    for b in ("one_segment", "two_segments"):
        sub = df[(df["block"] == b) & (df["data"] == "real")]
        for col in _FMT:
            vals = pd.to_numeric(sub[col], errors="coerce").dropna()
            if len(vals) > 1:
                best[(b, col)] = float(vals.min())
    return best


def _tex(df: pd.DataFrame) -> str:
    best = _best(df)
    lines = [
        "% Generated by lagsplat.report.krauss from metrics.json and lagsplat/report/data/krauss_published.csv; do not edit.",
        "% Paper Table 4 layout. MSE: image MSE over 0.5 s (30 states, 50 validation windows), pixels in [0,1];",
        "% AE: autoencoder floor; eps_freq on the depressurised tail (lagsplat.evaluate.krauss).",
        r"\begin{tabular*}{\columnwidth}{@{\extracolsep{\fill}}llccccc@{}}",
        r"\toprule",
        r"       &       &     & AE          & MSE          & $\varepsilon_{\mathrm{freq}}$ & Ext.  \\",
        r"Method & Dyn.  & $d$ & $(10^{-5})$ & $(10^{-3})$  & (\%) & force \\",
    ]
    surrogate = False
    for b, title in BLOCKS:
        sub = df[df["block"] == b]
        if not len(sub):
            continue
        lines += [r"\midrule", rf"\multicolumn{{7}}{{@{{}}l}}{{{title}}} \\"]
        for _, r in sub.iterrows():
            cells = []
            for col, fmt in _FMT.items():
                s = _num(r[col], fmt)
                if s != "--" and best.get((b, col)) == float(r[col]) and r["data"] == "real":
                    s = rf"\mathbf{{{s}}}"
                cells.append(s if s == "--" else f"${s}$")
            mark = ""
            if r["data"] == "surrogate":
                mark, surrogate = r"$^\dagger$", True
            d = _num(r["d"], ".0f")
            lines.append(
                f"{_tex_method(r['method'])}{mark} & {r['dynamics']}\\ & ${d}$ & " + " & ".join(cells) + f" & {_FORCE_TEX[r['ext_force']]} \\\\"
            )
    if surrogate:
        lines += [
            r"\midrule",
            r"\multicolumn{7}{@{}l}{\footnotesize $^\dagger$ simulated surrogate (lagsplat.synth.continuum\_robot), not the robot's recordings:} \\",
            r"\multicolumn{7}{@{}l}{\footnotesize not comparable with the published rows.} \\",
        ]
    lines += [r"\bottomrule", r"\end{tabular*}", ""]
    return "\n".join(lines)


def _md(df: pd.DataFrame) -> str:
    truth = "eps_freq_truth_pct" in df.columns
    head = ["Method", "Dyn.", "d", "AE (1e-5)", "MSE (1e-3)", "eps_freq (%)", "Ext. force", "Data", "Origin", "Source"]
    if truth:  # surrogate runs: the rollout's and the encoded tail's frequency against the simulator's
        head[6:6] = ["eps_freq vs simulator (%)", "encoded tail vs simulator (%)"]
    out = [
        "<!-- Generated by lagsplat.report.krauss from metrics.json and lagsplat/report/data/krauss_published.csv; do not edit. -->",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "|".join("---" for _ in head) + "|",
    ]
    titles = dict(BLOCKS)
    for b, _ in BLOCKS:
        sub = df[df["block"] == b]
        if not len(sub):
            continue
        title = titles[b].replace(r"\emph{", "").replace("}", "").replace(r"\S", "§")
        out.append(f"| **{title}** |" + " |" * (len(head) - 1))
        for _, r in sub.iterrows():
            cells = [
                str(r["method"]), str(r["dynamics"]), _num(r["d"], ".0f"),
                *(_num(r[c], f) for c, f in _FMT.items()),
                *((_num(r.get("eps_freq_truth_pct"), ".1f"), _num(r.get("eps_freq_enc_truth_pct"), ".2f")) if truth else ()),
                _FORCE_MD[r["ext_force"]], str(r["data"]), str(r["origin"]), str(r["source"]).replace("|", "/"),
            ]  # fmt: skip
            out.append("| " + " | ".join(cells) + " |")
    if (df["data"] == "surrogate").any():
        out += ["", "Rows with data = surrogate are on the simulated robot (lagsplat.synth.continuum_robot), not the real recordings; they are not comparable with the published rows."]
    return "\n".join(out) + "\n"


def krauss_table(
    one_segment: str | Path | None,
    two_segments: str | Path | None,
    ablation: Iterable[str | Path | list[str | Path]],
    out_tex: str | Path,
    published: str | Path | None = None,
    out_csv: str | Path | None = None,
    out_md: str | Path | None = None,
) -> tuple[Path, Path, Path]:
    """Write ``out_tex`` (paper Table 4 layout) and the same rows as ``out_csv`` and ``out_md`` (default: the ``.csv``
    and ``.md`` beside ``out_tex``).

    Args:
        one_segment, two_segments: our runs' ``metrics.json`` (missing: no row).
        ablation: the two-segment inertia variants' ``metrics.json`` (a list of
            them: one variant over seeds, its median row).
        out_tex: e.g. ``results/tables/krauss.tex``.
        published: the published-figures CSV (default the packaged one).

    Returns:
        ``(tex, csv, md)`` paths.

    Raises:
        ValueError: see :func:`krauss_rows`.
    """
    df = krauss_rows(one_segment, two_segments, list(ablation), load_published(published))
    out_tex = Path(out_tex)
    tex_p, csv_p = write_tex_csv(_tex(df), df, out_tex, out_csv)
    md_p = Path(out_md) if out_md is not None else out_tex.with_suffix(".md")
    with atomic_write(md_p) as tmp:
        tmp.write_text(_md(df))
    return tex_p, csv_p, md_p

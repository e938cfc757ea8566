"""Shared pieces of the benchmark scripts: timing, the environment header, the result table, the Markdown report.

Imported by the scripts as ``from _common import ...`` (a script's own folder
is first on ``sys.path``). Nothing heavy is imported at module level, so a
script can still set environment variables (``NUMBA_CACHE_DIR``) and import
:mod:`lagsplat` before torch.

Every script writes what it prints to ``results/benchmarks/<name>.md``
(:class:`Report`; ``--report PATH`` elsewhere, ``--no-report`` to only print):
the command line, the environment (machine, versions, threads, date, commit)
and the tables. These files are the record of the last measurement that the
documentation points to.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

#: The repository's root (this file's folder is ``benchmarks/``).
ROOT = Path(__file__).resolve().parents[1]
#: Where the reports go by default.
REPORTS = ROOT / "results" / "benchmarks"


def time_call(fn: Callable[[], object], repeats: int) -> float:
    """Median wall time (s) of ``repeats`` calls of ``fn``, after one untimed warm-up call."""
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def add_comparison_options(ap: argparse.ArgumentParser) -> None:
    """Add ``--against COMMIT`` (time another commit side by side, :func:`checkouts`), ``--rounds`` and the hidden
    ``--worker SETTING`` (the per-process timing a speed script runs in each checkout)."""
    ap.add_argument("--against", default=None, help="git commit to compare with, side by side")
    ap.add_argument("--rounds", type=int, default=2, help="alternating timing rounds per checkout")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)


@contextmanager
def checkouts(against: str | None) -> Iterator[dict[str, Path]]:
    """``{"this checkout": ROOT}``, and ``"against <commit>"``: a detached git worktree of ``against`` in a temporary
    folder (removed on exit) when a commit is named; a speed script times the same work in each, in one run."""
    roots = {"this checkout": ROOT}
    with tempfile.TemporaryDirectory() as tmp:
        if against:
            wt = Path(tmp) / "against"
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(wt), against], check=True)
            roots[f"against {against}"] = wt
        try:
            yield roots
        finally:
            if against:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(wt)], check=False)


def alternating_medians(roots: dict[str, Path], rounds: int, run: Callable[[Path], float]) -> dict[str, float]:
    """Median of ``run(root)`` over ``rounds`` rounds for each checkout of :func:`checkouts`, the checkouts alternating
    within each round (so a change of the machine's load falls on both)."""
    times: dict[str, list[float]] = {name: [] for name in roots}
    for _ in range(rounds):
        for name, root in roots.items():
            times[name].append(run(root))
    return {name: statistics.median(ts) for name, ts in times.items()}


def against_columns(medians: dict[str, float], label: str) -> dict[str, str]:
    """The other checkouts' figures (``"<label> against <commit>"``) and the speed-up, theirs over this checkout's."""
    base, cols = medians["this checkout"], {}
    for name, other in medians.items():
        if name != "this checkout":
            cols[f"{label} {name}"] = f"{other:.4f}"
            cols["speed-up"] = f"{other / base:.2f}x"
    return cols


def env_header(numba_info: str) -> str:
    """``"torch <version>: <n> threads; <numba_info>; machine CPUs: <n>"`` (torch must be importable)."""
    import torch

    return f"torch {torch.__version__}: {torch.get_num_threads()} threads; {numba_info}; machine CPUs: {os.cpu_count()}"


def format_table(table: pd.DataFrame, index: bool = False) -> str:
    """``table`` as markdown, or as plain text when tabulate is missing; with its index as the first column when ``index``."""
    try:
        return table.to_markdown(index=index)
    except ImportError:  # tabulate missing
        return table.to_string(index=index)


def print_table(rows: list[dict], file: TextIO | None = None) -> pd.DataFrame:
    """Print ``rows`` as one table after a blank line (:func:`format_table`) to ``file`` (default stdout); return the ``DataFrame``."""
    import pandas as pd

    table = pd.DataFrame(rows)
    print(file=file)
    print(format_table(table), file=file)
    return table


def measurable_gap_medians(rows: list[dict], metrics: Sequence[str]) -> dict[str, dict]:
    """Median gap reduction per metric over the effect clips whose gap stands out of the no-effect level.

    A reduction ``1 - after / before`` measures something only where there is
    a gap to shrink. Where an effect leaves a metric at the level the pipeline
    reaches with nothing missing (dry friction barely moves the frequency),
    ``before`` and ``after`` are two draws of the same noise and their ratio's
    median is about 0 (with a long negative tail) whatever the refit does. The
    no-effect level of a metric is read off the suite's own controls: the
    largest ``before`` among the control clips of the same system (plain and
    actuated). A clip's gap in that metric is *measurable* when its identified
    model's ``before`` exceeds it; the rest are counted as kept at the
    no-effect level when the refit's ``after`` stays at or below it.

    ``rows``: scored clips (``benchmarks/diagnosis.py``'s ``score``; ``system``, ``truth``, ``refit``,
    ``before``, ``after``, ``red_<metric>``; ``before`` and ``after`` map each metric to
    its value or ``None``). Returns, per metric of ``metrics``: ``median`` (``None`` without a measurable clip), ``n``
    measurable, ``n_refit`` effect clips with a reduction, ``n_kept`` of the
    ``n_refit - n`` others whose refit stays at or below the level,
    ``median_vs_control`` (the measurable clips' ``red_ctrl_<metric>``: the
    refit against the same fine-tune without the term), ``levels``
    (system -> no-effect level; systems without controls are left out, and so
    are their clips), and the second reading of the same clips:
    ``median_excess_removed``, the median share of the gap's excess over the
    level that the refit removes, ``min(1, (before - after) / (before - level))``
    (1: the refit brings the gap down to what the pipeline reaches with nothing
    missing; ``1 - after / before`` cannot exceed ``1 - level / before`` however
    good the refit, about 0.3 for a gap 1.5x the level), and ``n_at_level``, how
    many of them the refit brings to the level or below; and ``median_at_level``, what the plain
    reduction's median would read if every measurable clip's refit brought it exactly to the
    level, ``1 - level / before`` (the ceiling of a refit as good as the identified models with
    nothing missing: a median at or above it needs refits better than those). Where rows carry
    ``true_law`` (``{metric: value}``: what the clip's own ground-truth law scores in its chart,
    ``benchmarks/_oracle.py``), also ``median_true_law``, the median of ``1 - true_law / before`` over the
    measurable clips that have it (the reduction a refit that recovered the exact law would show:
    no refit's median can be expected above it), ``n_true_law`` of them, and
    ``n_at_true_law``, the refits among them whose ``after`` is at or below the true law's value.
    """
    out: dict[str, dict] = {}
    for k in metrics:
        levels: dict[str, float] = {}
        for r in rows:
            v = r["before"].get(k)
            if r["truth"] == "none" and v is not None:
                levels[r["system"]] = max(levels.get(r["system"], -np.inf), float(v))
        scored = [r for r in rows if r["truth"] != "none" and r["refit"] and r.get(f"red_{k}") is not None and r["system"] in levels]
        above = [r["before"].get(k) is not None and r["before"][k] > levels[r["system"]] for r in scored]
        meas = [r for r, a in zip(scored, above) if a]
        rest = [r for r, a in zip(scored, above) if not a]
        lv = lambda r: levels[r["system"]]  # noqa: E731
        kept = [r for r in rest if r["after"].get(k) is not None and r["after"][k] <= lv(r)]
        vs_ctrl = [r[f"red_ctrl_{k}"] for r in meas if r.get(f"red_ctrl_{k}") is not None]
        excess = [min(1.0, (r["before"][k] - r["after"][k]) / (r["before"][k] - lv(r))) for r in meas if r["after"].get(k) is not None]
        out[k] = {"median": float(np.median([r[f"red_{k}"] for r in meas])) if meas else None, "n": len(meas), "n_refit": len(scored),
                  "n_kept": len(kept), "median_vs_control": float(np.median(vs_ctrl)) if vs_ctrl else None, "levels": levels,
                  "median_excess_removed": float(np.median(excess)) if excess else None}  # fmt: skip
        out[k]["median_at_level"], out[k]["n_at_level"] = _ceiling(meas, k, lv)
        law = [r for r in meas if (r.get("true_law") or {}).get(k) is not None]
        out[k]["n_true_law"] = len(law)
        out[k]["median_true_law"], out[k]["n_at_true_law"] = _ceiling(law, k, lambda r: r["true_law"][k])
    return out


def _ceiling(rows: list[dict], k: str, reference) -> tuple[float | None, int]:
    """``(median of 1 - reference / before, how many refits' after is at or below the reference)`` over ``rows``
    for metric ``k``; ``reference(row)`` is a value of ``k`` (a no-effect level, or the true law's score)."""
    median = float(np.median([1.0 - reference(r) / r["before"][k] for r in rows])) if rows else None
    return median, sum(r["after"].get(k) is not None and r["after"][k] <= reference(r) for r in rows)


def realistic_verdict_ok(name: str, verdict: str) -> bool:
    """Whether a diagnosis ``verdict`` is right for the realistic-suite clip ``name`` (its effect: :func:`lagsplat.synth.realistic.clip_spec`).

    Right when it names the effect (``"none"`` for a clip without one), or, for a hardening spring
    (``cubic_stiffness`` whose ground truth, :func:`lagsplat.synth.realistic.motion_of`, is ``"hardening"``),
    also when it reads "nothing significant": a convex potential can absorb it. A softening spring must be named.

    Raises:
        KeyError: on an unknown clip name.
    """
    from lagsplat.synth.realistic import clip_spec, motion_of

    spec = clip_spec(name)
    if verdict == spec["effect"]:
        return True
    return spec["effect"] == "cubic_stiffness" and verdict == "none" and motion_of(spec).truth["effect_params"]["kind"] == "hardening"


def short_train_fraction(q: np.ndarray, t: np.ndarray, periods: float) -> float:
    """The training fraction of a realistic clip cut to ``periods`` periods of its true motion: ``periods / (f T)``,
    ``f`` (Hz) the spectral peak of the first true coordinate ``q [T, d]`` (:func:`lagsplat.timeseries.spectral_peak_frequency`),
    ``T`` the clip's span ``t[-1] - t[0]`` (s); rounded to 4 decimals (the short-clip protocol of ``realistic.py``)."""
    from lagsplat.timeseries import spectral_peak_frequency

    f = float(spectral_peak_frequency(q[:, :1], float(np.median(np.diff(t)))))
    return round(periods / (f * float(t[-1] - t[0])), 4)


def commit_counts(commits: Sequence[str]) -> str:
    """``"<commit> (<n> rows), ..."``: each commit the rows of a suite were measured at, with its count, sorted."""
    return ", ".join(f"{c} ({n} rows)" for c, n in sorted(Counter(commits).items()))


def score_verdicts(rows: list[dict], file: TextIO | None = None) -> tuple[pd.DataFrame, float, int, int]:
    """Print the per-clip table and the confusion matrix of a blind diagnosis run to ``file`` (default stdout).

    ``rows`` carry ``truth`` and ``verdict`` (effect names, ``"none"`` for a
    control) and ``ok`` (verdict correct). Both tables are printed by
    :func:`format_table`. Returns ``(table, top-1 accuracy, controls flagged,
    controls)``.
    """
    import pandas as pd

    table = print_table(rows, file=file)
    conf = pd.crosstab(table["truth"], table["verdict"], rownames=["truth"], colnames=["verdict"])
    print("\nconfusion matrix (rows: truth, columns: verdict)\n", file=file)
    print(format_table(conf, index=True), file=file)
    controls = table[table["truth"] == "none"]
    return table, float(table["ok"].mean()), int((controls["verdict"] != "none").sum()), len(controls)


def _cell(v: object) -> str:
    """A table cell as Markdown text: floats to 4 significant digits, missing as ``-``, ``|`` escaped."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    text = format(v, ".4g") if isinstance(v, float) else str(v)
    return text.replace("|", "\\|")


def markdown_table(table: pd.DataFrame, index: bool = False) -> str:
    """``table`` as a Markdown table whose cells are shown as the script formatted them (:func:`_cell`; strings are not re-parsed as numbers).

    Plain text when tabulate is missing.
    """
    shown = table.reset_index() if index else table
    shown = shown.rename(columns=_cell).astype(object).apply(lambda col: col.map(_cell))
    try:
        return shown.to_markdown(index=False, disable_numparse=True)
    except ImportError:  # tabulate missing
        return shown.to_string(index=False)


def add_report_options(ap: argparse.ArgumentParser, name: str) -> Path:
    """Add ``--report PATH`` (default ``results/benchmarks/<name>.md``) and ``--no-report`` (``args.report = None``) to ``ap``; return the default."""
    default = REPORTS / f"{name}.md"
    ap.add_argument("--report", type=Path, default=default, help=f"write the Markdown report here (default {default.relative_to(ROOT)})")
    ap.add_argument("--no-report", dest="report", action="store_const", const=None, help="print only, write no report")
    return default


def _cpu_model() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``; else :func:`platform.processor`)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def git_commit() -> str:
    """``<short hash>`` of the checkout, ``+ uncommitted changes`` when tracked files differ; ``unknown`` outside git.

    Read-only: ``GIT_OPTIONAL_LOCKS=0`` keeps ``git status`` from rewriting the index.
    """
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}

    def run(*a: str) -> str:
        return subprocess.run(["git", "-C", str(ROOT), *a], env=env, capture_output=True, text=True, timeout=30, check=True).stdout.strip()

    try:
        commit = run("rev-parse", "--short", "HEAD")
        dirty = run("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return commit + (" + uncommitted changes" if dirty else "")


def environment() -> dict[str, str]:
    """Machine, software and thread counts of this process, for a report's header (torch must be importable)."""
    import torch

    env = {
        "machine": f"{_cpu_model()}, {os.cpu_count()} CPUs; {platform.system()} {platform.machine()}; Python {platform.python_version()}",
        "vector": vector_extensions(),
        "torch": f"{torch.__version__}, {_threads(torch.get_num_threads())}",
    }
    if torch.cuda.is_available():
        env["GPU"] = torch.cuda.get_device_name()
    try:
        import numba

        env["numba"] = f"{numba.__version__}, {_threads(numba.get_num_threads())}"
    except ImportError:
        env["numba"] = "not installed"
    env["commit"] = git_commit()
    return env


def vector_extensions() -> str:
    """The CPU's widest vector extension and what the compiled kernels target: ``"AVX-512 (512-bit); numba target
    skylake-avx512; torch kernels AVX512"``. Read from ``/proc/cpuinfo`` flags (Linux), llvmlite's host CPU name
    (or ``NUMBA_CPU_NAME``) and torch's CPU capability (``ATEN_CPU_CAPABILITY`` lowers it); ``"unknown"`` parts
    where one is not available."""
    flags: set[str] = set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
                break
    except OSError:
        pass
    if "avx512f" in flags:
        widest = "AVX-512 (512-bit)"
    elif "avx2" in flags:
        widest = "AVX2 (256-bit)"
    elif "avx" in flags:
        widest = "AVX (256-bit)"
    elif flags:
        widest = "SSE only (128-bit)"
    else:
        widest = "unknown"
    try:
        import llvmlite.binding as llvm

        target = llvm.get_host_cpu_name()
    except (ImportError, RuntimeError):
        target = "unknown"
    try:
        import torch

        aten = torch.backends.cpu.get_cpu_capability()
    except (ImportError, AttributeError):
        aten = "unknown"
    return f"{widest}; numba target {os.environ.get('NUMBA_CPU_NAME') or target}; torch kernels {aten}"


def _threads(n: int) -> str:
    """``"1 thread"``, ``"<n> threads"``."""
    return f"{n} thread" + ("" if n == 1 else "s")


def _load() -> float:
    """The 1-minute load average (NaN where the system has none)."""
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def shown_path(path: str | Path) -> Path:
    """``path`` relative to the repository when it lies inside it (what a report shows), else as given."""
    p = Path(path)
    return p.resolve().relative_to(ROOT) if p.resolve().is_relative_to(ROOT) else p


def command_line(script: str | Path, argv: list[str] | None = None) -> str:
    """``python <script relative to the repository> <argv>`` as a shell would take it (``argv`` default: ``sys.argv[1:]``)."""
    script = Path(script).resolve()
    try:
        script = script.relative_to(ROOT)
    except ValueError:
        pass
    return shlex.join(["python", str(script), *(sys.argv[1:] if argv is None else argv)])


class Report:
    """A benchmark's Markdown report: what it prints, recorded as it is printed, written atomically by :meth:`write`.

    ``title`` heads the file; ``path`` is where it goes (``None``: nothing is
    written); ``script`` and ``argv`` give the command line (``argv`` default:
    ``sys.argv[1:]``). :meth:`text` and :meth:`table` print to stdout and keep
    the same content for the file; :meth:`write` puts the command, the date,
    the wall time since the report was created and :func:`environment` (read
    then, after the script has set its thread counts) under the title, then
    the recorded blocks. The load average at the start and at the end tells
    whether the machine was busy with anything else.
    """

    def __init__(self, title: str, path: str | Path | None, script: str | Path, argv: list[str] | None = None) -> None:
        self.title, self.path = title, None if path is None else Path(path)
        self.command = command_line(script, argv)
        self.blocks: list[str] = []
        self.started = datetime.now(timezone.utc)
        self._t0, self._load0 = time.perf_counter(), _load()

    def text(self, *lines: str) -> None:
        """Print ``lines`` and record them as one paragraph (lines joined by Markdown line breaks)."""
        for line in lines:
            print(line, flush=True)
        self.blocks.append("  \n".join(ln.strip() for ln in lines if ln.strip()))

    def block(self, markdown: str, echo: bool = True) -> None:
        """Record ``markdown`` (tables, lists) verbatim; print it as it is when ``echo``."""
        if echo:
            print(markdown, end="" if markdown.endswith("\n") else "\n", flush=True)
        self.blocks.append(markdown.strip("\n"))

    def table(self, rows: list[dict] | pd.DataFrame, title: str = "", index: bool = False) -> pd.DataFrame:
        """Print ``rows`` as a table (:func:`markdown_table`, after ``title`` when given) and record it; return the ``DataFrame``."""
        import pandas as pd

        table = rows if isinstance(rows, pd.DataFrame) else pd.DataFrame(rows)
        if title:
            print(f"\n{title}")
            self.blocks.append(title)
        text = markdown_table(table, index=index)
        print()
        print(text, flush=True)
        self.blocks.append(text)
        return table

    def markdown(self, **extra: str) -> str:
        """The report as Markdown; ``extra`` adds header items after the environment's."""
        wall = time.perf_counter() - self._t0
        head = {
            "command": f"`{self.command}`",
            "date": f"{self.started:%Y-%m-%d %H:%M} UTC (wall time {wall:.0f} s)",
            **environment(),
            "load average (1 min)": f"{self._load0:.2f} at the start, {_load():.2f} at the end (other processes slow the timings down)",
            **extra,
        }
        lines = [f"# {self.title}", "", *(f"- {k}: {v}" for k, v in head.items()), ""]
        for block in self.blocks:
            lines += [block, ""]
        return "\n".join(lines)

    def write(self, **extra: str) -> Path | None:
        """Write :meth:`markdown` to ``path`` atomically (a temporary file beside it, then ``os.replace``); the path, or ``None`` without one."""
        if self.path is None:
            return None
        from lagsplat.io.atomic import atomic_write

        with atomic_write(self.path) as tmp:
            tmp.write_text(self.markdown(**extra))
        print(f"\nreport: {self.path}")
        return self.path

"""Shared pieces of the benchmark scripts: timing, the environment header, the result table.

Imported by the scripts as ``from _common import ...`` (a script's own folder
is first on ``sys.path``). Nothing heavy is imported at module level, so a
script can still set environment variables (``NUMBA_CACHE_DIR``) and import
:mod:`lagsplat` before torch.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    import pandas as pd


def time_call(fn: Callable[[], object], repeats: int) -> float:
    """Median wall time (s) of ``repeats`` calls of ``fn``, after one untimed warm-up call."""
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


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

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
from typing import TYPE_CHECKING

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


def print_table(rows: list[dict]) -> pd.DataFrame:
    """Print ``rows`` as one table after a blank line (markdown, or plain text without tabulate); return the ``DataFrame``."""
    import pandas as pd

    table = pd.DataFrame(rows)
    print()
    try:
        print(table.to_markdown(index=False))
    except ImportError:  # tabulate missing
        print(table.to_string(index=False))
    return table


def score_verdicts(rows: list[dict]) -> tuple[pd.DataFrame, float, int, int]:
    """Print the per-clip table and the confusion matrix of a blind diagnosis run.

    ``rows`` carry ``truth`` and ``verdict`` (effect names, ``"none"`` for a
    control) and ``ok`` (verdict correct). Returns ``(table, top-1 accuracy,
    controls flagged, controls)``.
    """
    import pandas as pd

    table = print_table(rows)
    conf = pd.crosstab(table["truth"], table["verdict"], rownames=["truth"], colnames=["verdict"])
    print("\nconfusion matrix (rows: truth, columns: verdict)")
    print(conf.to_string())
    controls = table[table["truth"] == "none"]
    return table, float(table["ok"].mean()), int((controls["verdict"] != "none").sum()), len(controls)

"""Tests of the training-loop progress report (lagsplat.train.progress)."""

from __future__ import annotations

import io

from lagsplat.train.progress import Progress, format_seconds


def test_plain_lines_without_a_terminal() -> None:
    """A non-terminal stream gets plain lines with step, values, rate and ETA, and a closing line."""
    out = io.StringIO()
    bar = Progress(4, "stage1", stream=out, interval=0.0)
    seen = []
    for i in bar:
        bar.update(loss=0.5 / (i + 1))
        seen.append(i)
    assert seen == [0, 1, 2, 3]
    lines = out.getvalue().splitlines()
    assert len(lines) == 5  # one per step at interval 0, plus the closing line
    assert lines[0].startswith("stage1: step 1/4 (25%), loss 0.5, ") and "steps/s" in lines[0] and "ETA " in lines[0]
    assert lines[-1].startswith("stage1: step 4/4 (100%), loss 0.125, ") and "took " in lines[-1]
    assert "\r" not in out.getvalue()


def test_interval_limits_the_lines_and_disabled_prints_nothing() -> None:
    out = io.StringIO()
    assert list(Progress(50, "stage2", stream=out, interval=3600.0, unit="epoch")) == list(range(50))
    assert out.getvalue().splitlines() == [out.getvalue().splitlines()[0]]  # only the closing line
    assert out.getvalue().startswith("stage2: epoch 50/50 (100%), ")
    quiet = io.StringIO()
    assert len(list(Progress(3, "stage1", enabled=False, stream=quiet, interval=0.0))) == 3
    assert quiet.getvalue() == ""


def test_format_seconds() -> None:
    assert [format_seconds(s) for s in (0.4, 42, 235, 3725)] == ["0s", "42s", "3m55s", "1h02m"]

"""The results page (lagsplat.report.results_page) built from hand-made CSVs and PNGs, not from real runs.

Every table on the page must be its CSV cell for cell (a dropped row or a changed number fails), every figure a
copy under the size limit linked to the original, every item not built listed as such.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from lagsplat.report.paper import PaperItem, paper_items
from lagsplat.report.results_page import csv_markdown, main, results_page, shrink_png, write_results_page

ROWS = [
    ["system", "d", "eps_freq_pct", "eps_q", "eps_I_over_AE", "eps_AE_1e-4", "source", "held_out"],
    ["Pendulum (synthetic)", "1", "0.412345", "0.0812", "1.93", "0.734", "lagsplat.synth.pendulum, procedural", ""],
    ["Oscillating cart", "1", "1.2", "0.125", "13.6", "0.35", "a | b", "held out"],
    ["Apple pendulum", "1", "3.4e-05", "0.308", "", "1e+06", "", "no held-out validation (2.3 periods)"],
]


def _write_csv(path: Path, rows: list[list[str]]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    return path


def _write_png(path: Path, w: int, h: int, seed: int = 0) -> Path:
    """A PNG that compresses badly (noise), so that its full-size file is well over the page's limit."""
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)).save(path)
    return path


def _tables(md: str) -> list[list[list[str]]]:
    """Every Markdown table of ``md`` as rows of cells (header first, the separator line left out, ``\\|`` unescaped)."""
    tables, cur = [], None
    for line in md.splitlines():
        if line.startswith("|"):
            cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
            if all(re.fullmatch(r":?-+:?", c) for c in cells):
                continue
            cur = cur if cur is not None else []
            cur.append(cells)
        elif cur is not None:
            tables.append(cur)
            cur = None
    return tables + ([cur] if cur is not None else [])


def _items(tmp_path: Path) -> tuple[list[PaperItem], dict[str, Path]]:
    res = tmp_path / "results"
    files = {
        "physical": _write_csv(res / "tables" / "physical.csv", ROWS),
        "seeds": _write_csv(res / "tables" / "toy_seeds.csv", [["seed", "eps_q"], *[[str(k), f"0.{k}1"] for k in range(5)]]),
        "rollout": _write_png(res / "toy" / "figures" / "rollout.png", 900, 600),
        "small": _write_png(res / "cart" / "figures" / "forces.png", 40, 30),
        "report": res / "cart" / "diagnosis" / "report.md",
    }
    files["report"].parent.mkdir(parents=True)
    files["report"].write_text("# Diagnosis\n")
    (files["report"].parent / "report.json").write_text(json.dumps({"verdict": "coulomb", "verdict_text": "dry friction"}))
    s1, s2 = "Tables (paper §4.2)", "Figures"
    items = [
        PaperItem("physical", "table", str(files["physical"]), str(res / "tables" / "physical.tex"), s1, "Table 2 analogue."),
        PaperItem("seeds_toy", "table", str(files["seeds"]), str(res / "tables" / "toy_seeds.md"), s1, "Five seeds."),
        PaperItem("extrapolation", "table", str(res / "tables" / "extrapolation.csv"), str(res / "tables" / "extrapolation.tex"), s1, "Not built."),
        PaperItem("rollout_toy", "figure", str(files["rollout"]), str(files["rollout"]), s2, "A rollout."),
        PaperItem("forces", "figure", str(files["small"]), str(files["small"]), s2, "Forces."),
        PaperItem("orbit", "figure", str(res / "p3d" / "figures" / "novel_views.png"), str(res / "p3d" / "figures" / "novel_views.png"), s2, "Orbit."),
        PaperItem("diagnosis", "report", str(files["report"]), str(files["report"]), s2, "The gap."),
    ]
    return items, files


def test_each_table_is_its_csv_cell_for_cell(tmp_path):
    items, files = _items(tmp_path)
    page = tmp_path / "docs" / "results.md"
    status = write_results_page(items, page, tmp_path / "docs" / "results", commit="abc1234")
    text = page.read_text()
    tables = _tables(text)
    assert tables[0] == ROWS  # every row, every number as the CSV spells it (no rounding, no exponent rewritten)
    with open(files["seeds"], newline="") as f:
        assert tables[1] == list(csv.reader(f))
    assert len(tables) == 2  # the missing table is not drawn
    assert status == {"built": ["physical", "seeds_toy", "rollout_toy", "forces", "diagnosis"], "missing": ["extrapolation", "orbit"]}
    # each table with the command that builds it and the commit
    assert f"`snakemake -c2 {items[0].target}`" in text and "commit abc1234" in text


@pytest.mark.parametrize("change", ["drop_row", "change_number"])
def test_a_dropped_row_or_a_changed_number_is_caught(tmp_path, change):
    # the comparison above is strict: a page whose table lost a row or changed a digit no longer equals the CSV
    items, files = _items(tmp_path)
    md = csv_markdown(files["physical"])
    lines = md.splitlines()
    bad = "\n".join(lines[:-1]) if change == "drop_row" else md.replace("0.412345", "0.41234")
    assert _tables(md)[0] == ROWS
    assert _tables(bad)[0] != ROWS


def test_images_are_copied_under_the_size_limit_and_linked(tmp_path):
    items, files = _items(tmp_path)
    page, images = tmp_path / "docs" / "results.md", tmp_path / "docs" / "results"
    assert files["rollout"].stat().st_size > 1_000_000
    write_results_page(items, page, images, commit="abc1234", max_bytes=300_000)
    text = page.read_text()
    big, small = images / "rollout_toy.png", images / "forces.png"
    assert 0 < big.stat().st_size <= 300_000 and 0 < small.stat().st_size <= 300_000
    with Image.open(big) as im:
        assert im.format == "PNG" and im.width < 900 and abs(im.width / im.height - 1.5) < 0.02  # shrunk, aspect kept
    with Image.open(small) as im:
        assert im.size == (40, 30)  # already small: copied as it is
    assert "![A rollout.](results/rollout_toy.png)" in text and "*A rollout.*" in text
    assert "(../results/toy/figures/rollout.png)" in text  # the full-size file where the pipeline wrote it
    # a stale copy of a figure the page no longer shows goes
    (images / "old.png").write_bytes(b"x")
    write_results_page(items, page, images, commit="abc1234")
    assert not (images / "old.png").exists() and big.exists()


def test_missing_items_are_listed_as_not_built(tmp_path):
    items, _ = _items(tmp_path)
    text, status = results_page(items, tmp_path / "docs" / "results.md", tmp_path / "img", commit="abc1234")
    for it in items:
        if it.key in status["missing"]:
            assert f"not built yet: `{it.target}`" in text
    assert status["missing"] == ["extrapolation", "orbit"]
    assert "verdict: **coulomb**: dry friction" in text and "(../results/cart/diagnosis/report.md)" in text


def test_shrink_png_refuses_an_impossible_limit(tmp_path):
    src = _write_png(tmp_path / "a.png", 64, 64)
    with pytest.raises(ValueError, match="no copy"):
        shrink_png(src, tmp_path / "b.png", max_bytes=10)


def test_the_command_line_lists_the_paper_items_not_built(tmp_path, capsys):
    res = tmp_path / "res"
    _write_csv(res / "tables" / "physical.csv", ROWS)
    assert main(["--results", str(res), "--page", str(tmp_path / "results.md")]) == 0
    out = capsys.readouterr().out
    keys = [it.key for it in paper_items(res)]
    assert f"1 items built, {len(keys) - 1} not built yet" in out
    assert all(f"not built yet: {k}" in out for k in keys if k != "physical")
    assert _tables((tmp_path / "results.md").read_text())[0] == ROWS


def test_the_3d_table_is_the_novel_view_entries_of_metrics_json(tmp_path):
    # python -m lagsplat views_table: one row per 3-D system, the PSNR entries lagsplat.evaluate.views writes
    import subprocess
    import sys

    from lagsplat.report.tables import VIEW_COLUMNS

    values = {"psnr_train_views_train": 31.25, "psnr_novel_views_train": 27.5, "psnr_train_views_held_out": 30.125,
              "psnr_novel_views_held_out": 26.0625, "novel_view_gap_db_held_out": 4.0625}  # fmt: skip
    metrics = tmp_path / "res" / "pendulum3d" / "metrics.json"
    metrics.parent.mkdir(parents=True)
    metrics.write_text(json.dumps({"title": "Pendulum in 3-D", "d": 1, "metrics": {k: {"value": v} for k, v in values.items()}}))
    out_csv, out_md = tmp_path / "t" / "novel_views.csv", tmp_path / "t" / "novel_views.md"
    cmd = [sys.executable, "-m", "lagsplat", "views_table", f"results_dir={tmp_path / 'res'}", "table.name=novel_views", "'table.systems=[pendulum3d]'",
           f"'artifacts.table_inputs=[{metrics}]'", f"artifacts.table_csv={out_csv}", f"artifacts.table_md={out_md}"]  # fmt: skip
    r = subprocess.run(" ".join(cmd), shell=True, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    with open(out_csv, newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["system", "d", *VIEW_COLUMNS]
    assert rows[1] == ["Pendulum in 3-D", "1", *(f"{values[k]:g}" for k in VIEW_COLUMNS)]
    assert "| Pendulum in 3-D |" in out_md.read_text()

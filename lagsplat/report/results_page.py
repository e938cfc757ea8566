"""The results page: every table and figure of the paper the project builds, on one Markdown page a reader can check.

``python -m lagsplat.report.results_page`` (the last step of ``snakemake -c2 paper``) reads what the paper target
built (:func:`lagsplat.report.paper.paper_items`: paper §4.2 to §4.5, App. B and the gap diagnosis) and writes
``docs/results.md``:

* a table: its CSV re-rendered as a Markdown table, cell for cell (nothing parsed, rounded or dropped), the
  command that builds it, when the CSV was written and the git commit of the checkout (the tables record none of
  their own);
* a figure: a copy under ``docs/results/`` small enough to commit (PNG, shrunk until it is at most
  ``--max-kb``), linked to the full-size file where the pipeline wrote it, with its one-line caption;
* a report: a link to it and the verdict its JSON record gives;
* an item not built yet: ``not built yet: <target>``, never an error.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time
from pathlib import Path
from typing import Iterable

import pandas as pd

from lagsplat.io.atomic import atomic_write
from lagsplat.io.common import code_commit
from lagsplat.report.paper import PaperItem, paper_items

__all__ = ["MAX_BYTES", "csv_markdown", "shrink_png", "git_commit", "results_page", "write_results_page", "main"]

MAX_BYTES = 300_000
"""Largest copied image, bytes (``--max-kb``)."""


def csv_markdown(path: str | Path) -> str:
    """The CSV at ``path`` as a Markdown table, every cell as the CSV spells it (a ``|`` in a cell escaped).

    Raises:
        ValueError: if the file has no header row.
    """
    with open(path, newline="", encoding="utf-8") as f:
        rows = [r for r in csv.reader(f) if r]
    if not rows:
        raise ValueError(f"{path}: empty CSV, no header row")
    width = len(rows[0])
    cells = [[c.replace("|", "\\|").replace("\n", " ") for c in (r + [""] * width)[:width]] for r in rows]
    if len({*cells[0]}) < width:  # pandas needs unique column names; a repeated one keeps its text
        cells[0] = [c + "\u200b" * k for k, c in enumerate(cells[0])]
    return pd.DataFrame(cells[1:], columns=cells[0]).to_markdown(index=False, disable_numparse=True)


def shrink_png(src: str | Path, dst: str | Path, max_bytes: int = MAX_BYTES) -> Path:
    """Copy the image ``src`` to the PNG ``dst``, scaled down (aspect kept) until the file is at most ``max_bytes``.

    Raises:
        ValueError: if no size down to a few pixels fits ``max_bytes``.
    """
    from PIL import Image

    dst = Path(dst)
    with Image.open(src) as im:
        im.load()
        img = im.convert("RGBA" if "A" in im.getbands() or "transparency" in im.info else "RGB")
    scale = 1.0
    while True:
        size = (max(1, round(img.width * scale)), max(1, round(img.height * scale)))
        out = img if scale == 1.0 else img.resize(size, Image.LANCZOS)
        with atomic_write(dst) as tmp:
            out.save(tmp, format="PNG", optimize=True)
        if dst.stat().st_size <= max_bytes:
            return dst
        if max(size) <= 8:
            raise ValueError(f"{src}: no copy of at most {max_bytes} bytes")
        scale *= min(0.9, (max_bytes / dst.stat().st_size) ** 0.5)


def git_commit(where: str | Path | None = None) -> str:
    """Short hash of the checkout's commit (:func:`lagsplat.io.common.code_commit`), ``+ uncommitted changes`` when
    tracked files differ; ``unknown`` outside git."""
    c = code_commit(where)
    return "unknown" if c is None else c["commit"][:7] + (" + uncommitted changes" if c["dirty"] else "")


def _rel(path: str | Path, start: Path) -> str:
    """``path`` relative to the page's folder, with forward slashes (a Markdown link)."""
    return Path(os.path.relpath(Path(path).resolve(), start.resolve())).as_posix()


def _written(path: Path) -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(path.stat().st_mtime))


def _table(it: PaperItem, page_dir: Path, commit: str) -> list[str]:
    src = Path(it.path)
    return [
        f"- built by `{it.command}`; the CSV: [{src.name}]({_rel(src, page_dir)}), written {_written(src)}; commit {commit}",
        "",
        csv_markdown(src),
    ]


def _figure(it: PaperItem, page_dir: Path, images: Path, max_bytes: int) -> list[str]:
    src = Path(it.path)
    copy = shrink_png(src, images / f"{it.key}.png", max_bytes)
    return [
        f"![{it.caption}]({_rel(copy, page_dir)})",
        "",
        f"*{it.caption}* Full size: [{src.name}]({_rel(src, page_dir)}), written {_written(src)}; built by `{it.command}`.",
    ]


def _report(it: PaperItem, page_dir: Path) -> list[str]:
    src = Path(it.path)
    lines = [f"- [{src.name}]({_rel(src, page_dir)}), written {_written(src)}; built by `{it.command}`"]
    record = src.with_suffix(".json")
    if record.is_file():
        rec = json.loads(record.read_text())
        lines.append(f"- verdict: **{rec.get('verdict', '?')}**" + (f": {rec['verdict_text']}" if rec.get("verdict_text") else ""))
    return lines


def results_page(items: Iterable[PaperItem], page: str | Path, images: str | Path, commit: str | None = None,
                 max_bytes: int = MAX_BYTES) -> tuple[str, dict[str, list[str]]]:  # fmt: skip
    """The page's Markdown, and ``{"built": keys, "missing": keys}``; copies the figures into ``images`` (module docstring)."""
    items = list(items)
    page_dir, images = Path(page).parent, Path(images)
    commit = git_commit() if commit is None else commit
    built = [it for it in items if Path(it.path).is_file()]
    missing = [it for it in items if not Path(it.path).is_file()]
    out = [
        "# Results: every table and figure of the paper this project builds",
        "",
        "<!-- Generated by python -m lagsplat.report.results_page from what `snakemake -c2 paper` built; do not edit. -->",
        "",
        f"Page written {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} at commit {commit}; "
        f"{len(built)} of {len(items)} items built. Every table is its CSV cell for cell; every image a reduced copy "
        f"linked to the full-size file in the results folder. All of it: `snakemake -c2 paper`.",
    ]
    if missing:
        out += ["", "Not built yet:", ""] + [f"- not built yet: `{it.target}` ({it.key})" for it in missing]
    for section in dict.fromkeys(it.section for it in items):
        out += ["", f"## {section}"]
        for it in (i for i in items if i.section == section):
            out += ["", f"### {it.key}", "", it.caption if it.kind != "figure" or it in missing else "", ""]
            if it in missing:
                out.append(f"not built yet: `{it.target}` (`{it.command}`)")
            elif it.kind == "table":
                out += _table(it, page_dir, commit)
            elif it.kind == "figure":
                out += _figure(it, page_dir, images, max_bytes)
            else:
                out += _report(it, page_dir)
    text = "\n".join(line for k, line in enumerate(out) if line or (k and out[k - 1])) + "\n"  # no doubled blank lines
    return text, {"built": [it.key for it in built], "missing": [it.key for it in missing]}


def write_results_page(items: Iterable[PaperItem], page: str | Path, images: str | Path, commit: str | None = None,
                       max_bytes: int = MAX_BYTES) -> dict[str, list[str]]:  # fmt: skip
    """Write the page (:func:`results_page`) to ``page`` atomically and its images into ``images``, where a PNG the
    page no longer shows is removed (a figure no longer built leaves no stale copy); return ``{"built", "missing"}``."""
    images = Path(images)
    images.mkdir(parents=True, exist_ok=True)
    text, status = results_page(items, page, images, commit, max_bytes)
    shown = {f"{key}.png" for key in status["built"]}
    for stale in images.glob("*.png"):
        if stale.name not in shown:
            stale.unlink()
    with atomic_write(page) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return status


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring); prints one line per item not built yet."""
    ap = argparse.ArgumentParser(prog="python -m lagsplat.report.results_page", description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default="results", help="the pipeline's results_dir (default results)")
    ap.add_argument("--page", default="docs/results.md", help="the page written (default docs/results.md)")
    ap.add_argument("--images", default=None, help="folder of the copied images (default: docs/results beside the page)")
    ap.add_argument("--max-kb", type=float, default=MAX_BYTES / 1000, help="largest copied image, kB (default 300)")
    a = ap.parse_args(argv)
    page = Path(a.page)
    images = Path(a.images) if a.images else page.with_suffix("")
    status = write_results_page(paper_items(a.results), page, images, max_bytes=int(a.max_kb * 1000))
    print(f"[lagsplat] {page}: {len(status['built'])} items built, {len(status['missing'])} not built yet; images in {images}")
    for key in status["missing"]:
        print(f"[lagsplat]   not built yet: {key}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

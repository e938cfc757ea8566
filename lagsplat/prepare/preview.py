"""``prepare.png``: what automatic preparation chose, drawn before Stage 1 trains.

Three frames of the analysed clip (the first, one from the middle of the
motion, the last) with the object's region of interest (green) and every
moving part set aside (red, numbered as in the log); the object's path along
its principal direction against time, the frames where it moves shaded; and
the path's periodogram with the chosen peak. A refused clip is drawn as far as
the analysis got, under the refusal's line.
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import numpy as np

from lagsplat.io.atomic import atomic_write

__all__ = ["draw_preview"]


def _box(ax, box, colour: str, label: str | None = None, dashed: bool = False) -> None:
    from matplotlib.patches import Rectangle

    x0, y0, x1, y1 = box
    ax.add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, ec=colour, lw=1.5, ls="--" if dashed else "-"))
    if label:
        ax.text(x0, y0 - 1, label, color=colour, fontsize=7, va="bottom")


def draw_preview(path: str | Path, analysis: dict[str, Any], dt: float, title: str) -> Path:
    """Draw the preview figure (module docstring), atomically.

    Args:
        path: the PNG to write.
        analysis: :func:`lagsplat.prepare.analysis.analyse_motion`'s result (or the partial one a refusal carries);
            ``crop_in_analysis`` (optional) is the chosen crop in analysis pixels.
        dt: frame interval, s.
        title: the printed summary or the refusal's line.

    Returns:
        ``path`` as a Path.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = analysis["frames"]
    T = len(frames)
    kept = analysis.get("kept") or []
    span = analysis.get("span") or (0, T)
    fig = plt.figure(figsize=(10, 6.2))
    gs = fig.add_gridspec(2, 3, height_ratios=[1.3, 1])
    for j, i in enumerate((0, (span[0] + span[1]) // 2, T - 1) if T else ()):
        ax = fig.add_subplot(gs[0, j])
        ax.imshow(frames[i])
        ax.set_title(f"frame {i} ({i * dt:.1f} s)", fontsize=8)
        ax.axis("off")
        if analysis.get("crop_in_analysis"):
            _box(ax, analysis["crop_in_analysis"], "lime", "region of interest")
        elif "box" in analysis:
            _box(ax, analysis["box"], "lime", "object")
        for n, p in enumerate(analysis.get("dropped_parts") or [], 1):
            _box(ax, p.box, "red", f"set aside {n}", dashed=True)
    obj = kept[0] if kept else None
    ax = fig.add_subplot(gs[1, :2])
    if obj is not None:
        t = np.arange(T) * dt
        c = obj.xy - obj.xy[span[0] : span[1]].mean(0)
        ax.plot(t, c @ obj.direction, color="k", lw=1)
        ax.axvspan(span[0] * dt, (span[1] - 1) * dt, color="tab:green", alpha=0.12, label="moving")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("path along its principal direction (px)")
        ax.legend(fontsize=7, loc="upper right")
    else:
        ax.text(0.5, 0.5, "no moving part found", ha="center", va="center", transform=ax.transAxes)
    ax = fig.add_subplot(gs[1, 2])
    if obj is not None and len(obj.path) >= 8:
        n = len(obj.path)
        x = (obj.path - obj.path.mean()) * np.hanning(n)
        power = np.abs(np.fft.rfft(x, 8 * n)) ** 2
        freqs = np.fft.rfftfreq(8 * n, dt)
        ax.plot(freqs, power / max(power.max(), 1e-300), color="k", lw=1)
        if np.isfinite(obj.frequency_hz):
            ax.axvline(obj.frequency_hz, color="tab:green", lw=1, label=f"{obj.frequency_hz:.2f} Hz ({100 * obj.peak_share:.0f}% of the power)")
            ax.set_xlim(0, min(freqs[-1], 4 * obj.frequency_hz))
            ax.legend(fontsize=7)
        ax.set_xlabel("frequency (Hz)")
        ax.set_yticks([])
        ax.set_title("spectrum of the moving part", fontsize=8)
    fig.suptitle("\n".join(textwrap.wrap(title.replace("\n", "; "), 150)[:4]), fontsize=8)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(out) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return out

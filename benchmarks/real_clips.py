"""The real-clip test set: independent reference frequencies, and the score of the automatic preparation.

``benchmarks/real_clips/manifest.json`` lists public recordings of 1-DOF
oscillators (``benchmarks/real_clips/README.md``). This script has two jobs:

    python benchmarks/real_clips.py --reference [--only NAME ...] [--plots DIR]
    python benchmarks/real_clips.py --score --split test|tune|all

``--reference`` re-measures every clip's frequency without lagsplat's
preparation: a normalised-cross-correlation template tracker (OpenCV), started on
the box stored in the manifest, follows the object over the clip's frame range;
its 2-D path is projected on its principal direction, and the frequency is read
from the same-direction zero crossings (:func:`crossing_frequency`), with a
windowed spectral peak (:func:`lagsplat.timeseries.spectral_peak_frequency`) as
a cross-check. Clips whose manifest entry carries ``turning_frames`` (turning
points marked by hand) are measured from those instead. It prints both beside the
manifest's ``reference_hz``.

``--score`` runs :func:`lagsplat.prepare.prepare_video` on each clip of the split
and compares its ``frequency_hz`` with ``reference_hz`` (pass: relative error
<= 3 %); a refusal (``ClipError``) or any other exception is recorded and the
next clip runs. It writes ``results/benchmarks/real_clips_<split>.md`` and a
JSON file beside it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import resource
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402

#: The set's folder: ``manifest.json``, ``clips/``, ``README.md``.
SET_DIR = Path(__file__).resolve().parent / "real_clips"
MANIFEST = SET_DIR / "manifest.json"
#: Largest relative frequency error of a passing clip.
PASS_TOL = 0.03


def load_manifest(path: str | Path = MANIFEST) -> list[dict]:
    """The manifest's entries (a JSON list of dicts)."""
    return json.loads(Path(path).read_text())


def sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def clip_path(entry: dict) -> Path:
    """The stored video of a manifest entry (``file`` is relative to the set's folder)."""
    return SET_DIR / entry["file"]


def read_frames(path: str | Path, start: int = 0, stop: int | None = None, colour: bool = False) -> np.ndarray:
    """Frames ``[start, stop)`` of a video as float32 grey images ``[T, H, W]`` (0-255), decoded by OpenCV;
    with ``colour``, the BGR frames ``[T, H, W, 3]`` (for an object told apart by its colour alone).

    Raises:
        ValueError: the file cannot be opened or holds no frame in the range.
    """
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise ValueError(f"{path}: OpenCV cannot open it")
    frames, i = [], 0
    while True:
        ok, f = cap.read()
        if not ok or (stop is not None and i >= stop):
            break
        if i >= start:
            frames.append((f if colour else cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)).astype(np.float32))
        i += 1
    cap.release()
    if not frames:
        raise ValueError(f"{path}: no frame in [{start}, {stop})")
    return np.stack(frames)


def track_template(frames: np.ndarray, box: list[int], search_px: int = 40, update: float = 0.0) -> np.ndarray:
    """Follow the patch ``box`` of ``frames[0]`` through ``frames`` by normalised cross-correlation.

    Args:
        frames: grey frames ``[T, H, W]`` (or colour ``[T, H, W, 3]``: the match sums over the channels).
        box: ``[x0, y0, x1, y1]`` (px) of the object in the first frame.
        search_px: how far (px) the object may move between two frames; the match is sought within
            this margin around its last position.
        update: template blending weight per frame (0: the first frame's patch throughout; 0.1: the
            template follows slow changes of the object's look, a rotation).

    Returns:
        ``[T, 2]`` centre of the matched patch (px, ``x`` then ``y``), sub-pixel by a parabola through
        the correlation peak.
    """
    import cv2

    x0, y0, x1, y1 = (int(v) for v in box)
    tpl = frames[0, y0:y1, x0:x1].copy()
    th, tw = tpl.shape[:2]
    H, W = frames.shape[1:3]
    x, y = float(x0), float(y0)
    out = np.zeros((len(frames), 2))
    for i, f in enumerate(frames):
        if i:
            sx0, sy0 = max(0, int(round(x)) - search_px), max(0, int(round(y)) - search_px)
            sx1, sy1 = min(W, int(round(x)) + tw + search_px), min(H, int(round(y)) + th + search_px)
            res = cv2.matchTemplate(f[sy0:sy1, sx0:sx1], tpl, cv2.TM_CCOEFF_NORMED)
            _, _, _, (mx, my) = cv2.minMaxLoc(res)
            dx = dy = 0.0
            if 0 < mx < res.shape[1] - 1:
                a, b, c = res[my, mx - 1], res[my, mx], res[my, mx + 1]
                dx = 0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c < 0 else 0.0
            if 0 < my < res.shape[0] - 1:
                a, b, c = res[my - 1, mx], res[my, mx], res[my + 1, mx]
                dy = 0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c < 0 else 0.0
            x, y = sx0 + mx + dx, sy0 + my + dy
            if update > 0:
                xi, yi = int(round(x)), int(round(y))
                patch = f[yi : yi + th, xi : xi + tw]
                if patch.shape == tpl.shape:
                    tpl = (1 - update) * tpl + update * patch
        out[i] = (x + tw / 2.0, y + th / 2.0)
    return out


def principal_projection(path2d: np.ndarray) -> np.ndarray:
    """Coordinate of a ``[T, 2]`` path along its principal direction (px, mean removed), sign so that it starts >= 0."""
    c = path2d - path2d.mean(0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    s = c @ vt[0]
    return s if s[0] >= 0 else -s


def crossing_frequency(s: np.ndarray, fps: float, hysteresis: float = 0.15) -> tuple[float, int, list[float]]:
    """Frequency (Hz) from the same-direction (upward) crossings of a 1-D oscillation.

    The signal is centred on a straight line fitted to it (a slow drift of the rest position). An
    upward crossing counts only after the signal has gone below ``-hysteresis`` times its local
    level (the median of ``|s|`` over the preceding 30 samples), so noise about the rest position
    of a decayed motion adds no crossing. Crossing instants are interpolated linearly between
    samples.

    Args:
        s: samples (any unit), one per frame.
        fps: frames per second (Hz).
        hysteresis: fraction of the local level the signal must pass on the negative side.

    Returns:
        ``(frequency_hz, periods, crossing_frames)``: ``periods`` = crossings - 1, frequency =
        periods / time between the first and last crossing; ``nan`` with fewer than 2 crossings.
    """
    n = len(s)
    t = np.arange(n)
    s = s - np.polyval(np.polyfit(t, s, 1), t)
    a = np.abs(s)
    crossings: list[float] = []
    armed = False
    for i in range(1, n):
        local = np.median(a[max(0, i - 30) : i + 1]) + 1e-9
        if s[i] < -hysteresis * local:
            armed = True
        if armed and s[i - 1] < 0 <= s[i]:
            crossings.append(i - 1 + (-s[i - 1]) / (s[i] - s[i - 1]))
            armed = False
    if len(crossings) < 2:
        return float("nan"), 0, crossings
    periods = len(crossings) - 1
    return periods * fps / (crossings[-1] - crossings[0]), periods, crossings


def turning_points(s: np.ndarray, min_prominence: float = 0.2) -> list[float]:
    """Frames of the alternating extremes (turning points) of a 1-D oscillation, sub-frame by a parabola.

    Args:
        s: samples, one per frame.
        min_prominence: an extreme counts when it stands out by this fraction of the signal's range.

    Returns:
        Turning-point frames (relative to ``s[0]``), alternately maxima and minima.
    """
    from scipy.signal import find_peaks

    prom = min_prominence * float(np.ptp(s))
    ext = sorted([(int(i), 1) for i in find_peaks(s, prominence=prom)[0]] + [(int(i), -1) for i in find_peaks(-s, prominence=prom)[0]])
    keep: list[tuple[int, int]] = []
    for i, kind in ext:  # alternate: of two same-kind neighbours keep the more extreme
        if keep and keep[-1][1] == kind:
            if kind * s[i] > kind * s[keep[-1][0]]:
                keep[-1] = (i, kind)
            continue
        keep.append((i, kind))
    out = []
    for i, _ in keep:
        a, b, c = s[i - 1], s[i], s[i + 1]
        den = a - 2 * b + c
        out.append(i + (0.5 * (a - c) / den if den != 0 else 0.0))
    return out


def turning_frequency(turning_frames: list[float], fps: float) -> tuple[float, int]:
    """Frequency (Hz) from hand-marked turning points (frame numbers, alternately one extreme and the other).

    Consecutive turning points are half a period apart: ``f = (k - 1) / 2 / (time between first and last)``.

    Raises:
        ValueError: fewer than 3 turning points.
    """
    k = len(turning_frames)
    if k < 3:
        raise ValueError(f"need at least 3 turning points, got {k}")
    span = (turning_frames[-1] - turning_frames[0]) / fps
    return (k - 1) / 2.0 / span, (k - 1) // 2


def kymograph_frequency(
    frames: np.ndarray, columns: list[int], rows: list[int], threshold: float, prominence: float, min_gap: int, fps: float
) -> tuple[float, int, np.ndarray]:
    """Frequency (Hz) of a vertical oscillation too blurred to track, from its kymograph.

    Each frame's strip ``columns = [x0, x1]`` is averaged across to one column of grey levels; a row
    departs where it differs from that row's median over the range by more than ``threshold`` grey
    levels, and the object's lowest point is the lowest departing row within ``rows = [y0, y1]``.
    Its maxima (one per period, at least ``prominence`` px deep and ``min_gap`` frames apart) are same-phase events:
    ``f = (k - 1) / (time between the first and the last)``.

    Returns:
        ``(hz, periods, y)``: ``y [T]`` the lowest point per frame (px; ``nan`` where nothing departs).

    Raises:
        ValueError: fewer than 2 maxima.
    """
    from scipy.signal import find_peaks

    K = frames[:, :, columns[0] : columns[1]].astype(np.float32).mean(2)  # [T, H]
    dep = np.abs(K - np.median(K, 0))[:, rows[0] : rows[1]] > threshold
    y = np.array([rows[0] + np.flatnonzero(d)[-1] if d.any() else np.nan for d in dep])
    s = np.nan_to_num(y - np.nanmedian(y))
    peaks, _ = find_peaks(s, prominence=prominence, distance=min_gap)
    if len(peaks) < 2:
        raise ValueError(f"need at least 2 maxima of the kymograph's lowest point, got {len(peaks)}")
    return (len(peaks) - 1) / ((peaks[-1] - peaks[0]) / fps), len(peaks) - 1, y


def measure_reference(entry: dict, plot: str | Path | None = None) -> dict:
    """Re-measure one manifest entry's reference frequency, without lagsplat's preparation.

    Uses ``entry["turning_frames"]`` when present (hand-marked), then ``entry["reference_kymograph"]``
    (:func:`kymograph_frequency`: ``columns``, ``rows``, ``threshold``, ``prominence``, ``min_gap``; for a motion too
    blurred to track), else the template tracker on
    ``entry["reference_track"]`` (``box`` in the first frame of ``frames``, ``search_px``,
    ``update``; optional ``measure`` ``[a, b]``: the sub-range, relative to ``frames[0]``, where the
    object moves, default all; ``count``: ``"crossings"`` (default, :func:`crossing_frequency`) or
    ``"turning"`` (:func:`turning_points`, for clips with too few crossings)).

    Returns:
        ``{"hz", "periods", "spectral_hz", "method", "frames_tracked"}`` (``spectral_hz`` is ``nan``
        for hand-marked clips).

    Raises:
        ValueError: an entry with neither ``turning_frames`` nor ``reference_track``, or an
            unreadable clip.
    """
    from lagsplat.timeseries import spectral_peak_frequency

    fps = float(entry["fps"])
    if entry.get("turning_frames"):
        hz, periods = turning_frequency(entry["turning_frames"], fps)
        return {"hz": hz, "periods": periods, "spectral_hz": float("nan"), "method": "hand-marked turning points", "frames_tracked": 0}
    if entry.get("reference_kymograph"):
        rk = entry["reference_kymograph"]
        start, stop = entry["frames"]
        frames = read_frames(clip_path(entry), start, stop)
        hz, periods, y = kymograph_frequency(frames, rk["columns"], rk["rows"], rk["threshold"], rk["prominence"], rk["min_gap"], fps)
        spec = spectral_peak_frequency(np.nan_to_num(y - np.nanmedian(y)), 1.0 / fps)
        return {"hz": hz, "periods": periods, "spectral_hz": spec, "method": "kymograph of a vertical strip, lowest point's maxima", "frames_tracked": len(y)}
    rt = entry.get("reference_track")
    if not rt:
        raise ValueError(f"{entry['name']}: neither turning_frames, reference_kymograph nor reference_track in the manifest")
    start, stop = entry["frames"]
    frames = read_frames(clip_path(entry), start, stop, colour=bool(rt.get("colour", False)))
    xy = track_template(frames, rt["box"], rt.get("search_px", 40), rt.get("update", 0.0))
    a, b = rt.get("measure", [0, None])
    xy = xy[a:b]
    s = principal_projection(xy) if rt.get("axis", "principal") == "principal" else xy[:, 0 if rt["axis"] == "x" else 1] - xy[:, 0 if rt["axis"] == "x" else 1].mean()
    if rt.get("count", "crossings") == "turning":
        cross = turning_points(s)
        hz, periods = turning_frequency(cross, fps)
        method = "template tracker, principal direction, turning points"
    else:
        hz, periods, cross = crossing_frequency(s, fps)
        method = "template tracker, principal direction, zero crossings"
    spec = spectral_peak_frequency(s, 1.0 / fps)
    if plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(1, 2, figsize=(11, 3.2))
        ax[0].plot(xy[:, 0], xy[:, 1], lw=0.8)
        ax[0].invert_yaxis()
        ax[0].set_title(f"{entry['name']}: tracked path (px)")
        ax[0].set_aspect("equal", "datalim")
        ax[1].plot(np.arange(len(s)) + start + a, s, lw=0.8)
        for c in cross:
            ax[1].axvline(c + start + a, color="r", lw=0.5)
        ax[1].set_title(f"principal coordinate; {hz:.4f} Hz ({periods} periods), spectral {spec:.4f} Hz")
        ax[1].set_xlabel("frame")
        fig.tight_layout()
        fig.savefig(plot, dpi=80)
        plt.close(fig)
    return {"hz": hz, "periods": periods, "spectral_hz": spec, "method": method, "frames_tracked": len(xy)}


def run_reference(entries: list[dict], plots: Path | None) -> None:
    """Print each entry's re-measured reference beside the manifest's."""
    if plots is not None:
        plots.mkdir(parents=True, exist_ok=True)
    print(f"{'clip':24s} {'manifest Hz':>11s} {'measured Hz':>11s} {'periods':>7s} {'spectral Hz':>11s} {'rel diff':>8s}  method")
    for e in entries:
        t0 = time.process_time()
        r = measure_reference(e, None if plots is None else plots / f"{e['name']}.png")
        diff = (r["hz"] - e["reference_hz"]) / e["reference_hz"] if e.get("reference_hz") else float("nan")
        print(f"{e['name']:24s} {e.get('reference_hz', float('nan')):11.4f} {r['hz']:11.4f} {r['periods']:7d} {r['spectral_hz']:11.4f} {diff:+8.2%}  {r['method']} ({time.process_time() - t0:.1f} s CPU)")


def run_score(entries: list[dict], split: str, report: Path | None) -> list[dict]:
    """Run the preparation on each entry, compare its frequency with the reference; write the report and JSON."""
    from _common import Report

    rep = Report(f"Automatic preparation on the real clips ({split} split)", report, __file__)
    rows = []
    for e in entries:
        row = {"clip": e["name"], "split": e["split"], "nuisances": ", ".join(e.get("nuisances", [])), "reference_hz": e["reference_hz"]}
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            from lagsplat.io.clip import ClipError
            from lagsplat.prepare import prepare_video

            start, stop = e["frames"]
            prep = prepare_video(clip_path(e), fps=e.get("fps"), start=start, stop=stop)
            f = float(prep.frequency_hz)
            err = abs(f - e["reference_hz"]) / e["reference_hz"]
            row.update(frequency_hz=f, rel_error=err, status="pass" if err <= PASS_TOL else "fail", crop=str(prep.crop), resize=str(prep.resize), note="")
        except ClipError as exc:  # a refusal: recorded, the next clip runs
            row.update(frequency_hz=None, rel_error=None, status="refused", note=str(exc).replace("\n", " ")[:300])
        except Exception as exc:  # noqa: BLE001 - one broken clip must not stop the others
            row.update(frequency_hz=None, rel_error=None, status="error", note=f"{type(exc).__name__}: {exc}"[:300])
            traceback.print_exc()
        row["wall_s"], row["cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
        print(f"{e['name']}: {row['status']} ({row['cpu_s']:.1f} s CPU, {row['wall_s']:.1f} s wall)", flush=True)
        rows.append(row)
    n_pass = sum(r["status"] == "pass" for r in rows)
    rep.text(f"pass (relative frequency error <= {PASS_TOL:.0%}): {n_pass} of {len(rows)}; refused: "
             f"{sum(r['status'] == 'refused' for r in rows)}; errors: {sum(r['status'] == 'error' for r in rows)}; "
             f"peak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")  # fmt: skip
    rep.table(rows)
    if report is not None:
        rep.write()
        report.with_suffix(".json").write_text(json.dumps({"split": split, "tolerance": PASS_TOL, "rows": rows}, indent=1))
        print(f"json: {report.with_suffix('.json')}")
    return rows


def main() -> None:
    """Parse the command line and run ``--reference`` or ``--score``."""
    from _common import REPORTS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    job = ap.add_mutually_exclusive_group(required=True)
    job.add_argument("--reference", action="store_true", help="re-measure the reference frequencies")
    job.add_argument("--score", action="store_true", help="score lagsplat.prepare.prepare_video")
    ap.add_argument("--split", choices=["test", "tune", "all"], default="test")
    ap.add_argument("--only", nargs="*", default=None, help="clip names (default: all of the split)")
    ap.add_argument("--plots", type=Path, default=None, help="--reference: write the tracked paths here as PNG")
    ap.add_argument("--report", type=Path, default=None, help="--score: Markdown report (default results/benchmarks/real_clips_<split>.md)")
    ap.add_argument("--no-report", action="store_true", help="--score: print only")
    args = ap.parse_args()
    entries = load_manifest()
    if args.only:
        entries = [e for e in entries if e["name"] in args.only]
    elif args.split != "all":
        entries = [e for e in entries if e["split"] == args.split]
    if args.reference:
        run_reference(entries, args.plots)
    else:
        report = None if args.no_report else (args.report or REPORTS / f"real_clips_{args.split}.md")
        run_score(entries, args.split, report)


if __name__ == "__main__":
    main()

"""Independent frequency of the real clips, by colour tracking in the raw frames.

Ground truth for ``eps_freq`` on real recordings, computed without lagsplat's
encoder: the object's colour centroid is tracked in every raw frame, and the
same spectral estimator (:func:`lagsplat.timeseries.spectral_peak_frequency`) is
applied to its horizontal position over the clip's held-out segment (the same
frame range and split as ``results/<system>/clip.npz``) and over the whole clip.

    python benchmarks/track_real_clips.py --raw-dir ../shared/data/real

Prints one row per clip: tracked frequencies, and, when
``results/<system>/metrics.json`` exists, the model's rollout frequency and its
error against the tracked one; writes them to
``results/benchmarks/track_real_clips.md`` (``--report PATH``, ``--no-report``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402
from _common import Report, add_report_options  # this script's folder

from lagsplat.io.video import read_video  # noqa: E402
from lagsplat.timeseries import spectral_peak_frequency  # noqa: E402

# system -> (file, fps override, colour mask on RGB float frames, row band)
CLIPS = {
    "oscillating_cart": (
        "oscillating_cart.webm",
        30.0,
        lambda r, g, b: (g > 150) & (g - r > 60) & (g - b > 40),  # the green marker on the cart
        (200, 360),
    ),
    "red_apple_pendulum": (
        "red_apple_pendulum.mov",
        None,
        lambda r, g, b: (r > 100) & (r - g > 60) & (r - b > 50),  # the red apple
        (0, 360),
    ),
}


def track(path: Path, fps: float | None, mask_fn, band: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Colour-centroid x position (pixels) per frame and the timestamps (s)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames, t, _ = read_video(path, fps=fps)
    xs = np.full(len(frames), np.nan)
    for i, f in enumerate(frames):
        f = f[band[0] : band[1]].astype(np.float32)
        m = mask_fn(f[..., 0], f[..., 1], f[..., 2])
        if m.sum() > 5:
            xs[i] = np.nonzero(m)[1].mean()
    return xs, t


def main() -> None:
    """Print the tracked frequencies and compare with metrics.json where present."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--raw-dir", default="data/raw")
    ap.add_argument("--results", default="results")
    add_report_options(ap, "track_real_clips")
    args = ap.parse_args()
    import yaml

    rep = Report("Frequency of the real clips by colour tracking", args.report, __file__)

    rows = []
    for system, (fname, fps, mask_fn, band) in CLIPS.items():
        path = Path(args.raw_dir) / fname
        if not path.exists():
            rep.text(f"{system}: {path} not found, skipped")
            continue
        xs, t = track(path, fps, mask_fn, band)
        conf = yaml.safe_load((Path(__file__).resolve().parents[1] / "conf" / "system" / f"{system}.yaml").read_text())["system"]
        start, stop = conf.get("frames") or [0, None]
        xs = xs[start:stop]
        dt = float(np.median(np.diff(t)))
        n_train = int(conf["split"]["train_fraction"] * len(xs))
        ok = np.isfinite(xs)
        f_all = spectral_peak_frequency(np.interp(np.arange(len(xs)), np.flatnonzero(ok), xs[ok]), dt)
        ho = xs[n_train:]
        f_ho = spectral_peak_frequency(np.interp(np.arange(len(ho)), np.flatnonzero(np.isfinite(ho)), ho[np.isfinite(ho)]), dt)
        row = {"system": system, "tracked_frames": int(ok.sum()), "of": len(xs), "f_track_all_hz": f_all, "f_track_held_out_hz": f_ho}
        mpath = Path(args.results) / system / "metrics.json"
        if mpath.exists():
            m = json.loads(mpath.read_text())["metrics"]
            row["f_enc_hz"] = m["f_enc_hz"]["value"]
            row["f_sim_hz"] = m["f_sim_hz"]["value"]
            row["eps_freq_vs_track"] = abs(m["f_sim_hz"]["value"] - f_ho) / f_ho
            row["eps_freq"] = m["eps_freq"]["value"]
        rows.append(row)
    import pandas as pd

    rep.table(pd.DataFrame(rows).round(4))
    rep.write()


if __name__ == "__main__":
    main()

"""Novel viewpoints of a 3-D model: PSNR of the decoded views against the cached views (paper §3.2, App. C).

Each frame is encoded from the main camera, and the 3-D decoder renders that state through every view
camera (:class:`~lagsplat.models.decoder3d.ConditionedGaussians3D`). Against the cached views
(:mod:`lagsplat.views`) this gives, per camera, the PSNR (scikit-image's ``peak_signal_noise_ratio``,
``data_range`` 1, mean over frames) on training and on held-out frames. The *training views' AE floor* is the
PSNR over the cameras Stage 1 trained on (the main camera and the views not held out); the held-out cameras
(``system.views.holdout``), never seen in training, are the novel views, and ``novel_view_gap_db`` is floor
minus novel on the same frames.
"""

from __future__ import annotations

import numpy as np
import torch
from skimage.metrics import peak_signal_noise_ratio

from lagsplat.evaluate.common import metric_entry
from lagsplat.io.clip import Clip
from lagsplat.models.autoencoder import AutoEncoder, frames_to_tensor
from lagsplat.views import ViewSet

__all__ = ["view_psnr", "view_metrics"]


@torch.no_grad()
def view_psnr(ae: AutoEncoder, clip: Clip, views: ViewSet, frames: np.ndarray, batch: int = 32) -> np.ndarray:
    """PSNR (dB) of every camera at the given clip frames: ``[len(frames), M + 1]``, column 0 the main camera.

    Raises:
        ValueError: if the decoder is not a 3-D one (it has no cameras to render through).
    """
    if ae.decoder.n_space != 3:
        raise ValueError("novel views need the 3-D decoder (stage1.decoder=conditioned3d)")
    out = np.empty((len(frames), views.n_views + 1))
    for s in range(0, len(frames), batch):
        idx = frames[s : s + batch]
        z = ae.encode(frames_to_tensor(clip.images[idx]))
        for m in range(views.n_views + 1):
            target = clip.images[idx] if m == 0 else views.images[idx, m - 1]
            h, w = target.shape[1:3]
            rec = ae.decoder.render(z, h, w, camera=views.cameras[m])[0].permute(0, 2, 3, 1).double().numpy()
            for j in range(len(idx)):
                out[s + j, m] = peak_signal_noise_ratio(target[j].astype(np.float64) / 255.0, rec[j], data_range=1.0)
    return out


def view_metrics(ae: AutoEncoder, clip: Clip, views: ViewSet, max_frames: int = 60) -> dict:
    """The novel-view entries of ``metrics.json`` (module docstring), on at most ``max_frames`` evenly spaced
    training frames and as many held-out frames."""
    out: dict = {}
    train_cams = [0] + [m + 1 for m in views.train_views]
    novel_cams = [m + 1 for m in views.holdout]
    for part, idx in (("train", clip.train_idx), ("held_out", clip.held_out_idx)):
        if len(idx) == 0:
            continue
        idx = idx[np.unique(np.linspace(0, len(idx) - 1, min(len(idx), max_frames)).round().astype(int))]
        p = view_psnr(ae, clip, views, idx)
        floor = float(p[:, train_cams].mean())
        frames = f"{len(idx)} {part.replace('_', '-')} frames"
        out[f"psnr_train_views_{part}"] = metric_entry(floor, "PSNR of the decoded main camera and training views at the encoded state (the views' AE floor)", frames, "dB")
        out[f"psnr_per_camera_{part}"] = metric_entry(p.mean(0).tolist(), "PSNR per camera, main camera first, then the cached views", frames, "dB")
        if novel_cams:
            novel = float(p[:, novel_cams].mean())
            out[f"psnr_novel_views_{part}"] = metric_entry(novel, f"PSNR of the held-out cameras {views.holdout} (never trained on)", frames, "dB")
            out[f"novel_view_gap_db_{part}"] = metric_entry(floor - novel, "training views' AE floor minus the novel views' PSNR", frames, "dB")
    return out

"""Novel views of an identified 3-D model: an orbit video and a contact sheet (paper teaser and Fig. 9 style).

The 3-D decoder (:class:`~lagsplat.models.decoder3d.ConditionedGaussians3D`) renders a latent state through any
camera. :func:`novel_view_frames` renders states along a camera path (an orbit through the main camera around
the point the cameras look at, :func:`lagsplat.render.camera.orbit_through`, or cameras from a JSON file),
one state per camera or one state for all; :func:`write_novel_views` writes them as an MP4 (OpenCV) and a
contact sheet (matplotlib).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import cv2  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from lagsplat.io.atomic import atomic_write  # noqa: E402
from lagsplat.models.decoder3d import ConditionedGaussians3D  # noqa: E402
from lagsplat.render.camera import Camera  # noqa: E402

__all__ = ["novel_view_frames", "write_novel_views"]


@torch.no_grad()
def novel_view_frames(decoder: ConditionedGaussians3D, z: torch.Tensor, cameras: list[Camera], height: int, width: int) -> np.ndarray:
    """Render raw latent states through cameras: ``z [1,d]`` (one state, every camera) or ``[len(cameras), d]``
    (state ``k`` through camera ``k``). Returns uint8 ``[len(cameras), height, width, 3]``.

    Raises:
        ValueError: for a decoder that is not 3-D, or a number of states that is neither 1 nor one per camera.
    """
    if decoder.n_space != 3:
        raise ValueError("novel views need the 3-D decoder (stage1.decoder=conditioned3d)")
    if z.shape[0] not in (1, len(cameras)):
        raise ValueError(f"{z.shape[0]} states for {len(cameras)} cameras: give one state or one per camera")
    out = np.empty((len(cameras), height, width, 3), np.uint8)
    geom = decoder.geometry()
    for k, cam in enumerate(cameras):
        img = decoder.render(z[k if z.shape[0] > 1 else 0][None], height, width, geom=geom, camera=cam)[0][0]
        out[k] = (img.permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.uint8)
    return out


def write_novel_views(frames: np.ndarray, video: str | Path, sheet: str | Path, fps: float = 15.0, title: str = "", n_sheet: int = 8) -> tuple[Path, Path]:
    """Write ``frames`` (uint8 ``[N,H,W,3]``) as an MP4 video and a contact sheet of ``n_sheet`` evenly spaced frames,
    atomically each. Returns both paths.

    Raises:
        RuntimeError: naming the file, if OpenCV cannot write the video.
    """
    video, sheet = Path(video), Path(sheet)
    video.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(video) as tmp:
        tmp_mp4 = tmp.with_suffix(".mp4")
        w = cv2.VideoWriter(str(tmp_mp4), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (frames.shape[2], frames.shape[1]))
        if not w.isOpened():
            raise RuntimeError(f"{video}: OpenCV cannot write an MP4 here")
        for f in frames:
            w.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
        w.release()
        tmp_mp4.replace(tmp)
    picks = np.unique(np.linspace(0, len(frames) - 1, min(n_sheet, len(frames))).round().astype(int))
    fig, axes = plt.subplots(1, len(picks), figsize=(1.8 * len(picks), 2.1), squeeze=False)
    for ax, k in zip(axes[0], picks):
        ax.imshow(frames[k])
        ax.set_title(f"view {k}", fontsize=8)
        ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    with atomic_write(sheet) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return video, sheet

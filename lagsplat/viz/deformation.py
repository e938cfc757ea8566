"""The two decoders' velocity fields side by side (paper App. B, Fig. deform-velocity).

For each decoder, the rendered frame at the compared state beside the same
primitives coloured by their image speed ``|J_i qdot|`` (px/s, one colour
scale for both) and rasterised with the same kernel, opacities and
covariances (:meth:`~lagsplat.models.decoder.ConditionedGaussians.render`
with the colours as ``extra`` channels).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lagsplat.io.atomic import atomic_write
from lagsplat.models.autoencoder import AutoEncoder

__all__ = ["speed_render", "deformation_figure"]


@torch.no_grad()
def speed_render(ae: AutoEncoder, z: np.ndarray, speed: np.ndarray, vmax: float, cmap: str = "magma") -> np.ndarray:
    """The primitives at the raw latent ``z [d]`` coloured by ``speed [K]`` (px/s, scaled by ``vmax``): ``[H,W,3]`` in [0, 1]."""
    import matplotlib

    colors = matplotlib.colormaps[cmap](np.clip(np.asarray(speed) / max(vmax, 1e-12), 0.0, 1.0))[:, :3]
    zz = torch.as_tensor(np.asarray(z), dtype=torch.float32).reshape(1, -1)
    _, img = ae.decoder.render(zz, ae.height, ae.width, extra=torch.as_tensor(colors, dtype=torch.float32))
    return img[0].clamp(0.0, 1.0).permute(1, 2, 0).numpy()


def deformation_figure(panels: list[dict], frame: np.ndarray, out_path: str | Path, title: str = "") -> Path:
    """Write the figure: the clip's frame, then per decoder its render and its speed-coloured render.

    Args:
        panels: one dict per decoder: ``name``, ``image [H,W,3]`` in [0, 1], ``speed_image [H,W,3]``,
            ``roughness`` (px/s), ``vmax`` (px/s, the shared colour scale).
        frame: uint8 ``[H,W,3]``, the training frame of the compared state.
        out_path: PNG path (written atomically).
        title: figure title.

    Returns:
        ``out_path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    H, W = frame.shape[:2]
    n = len(panels)
    width = 7.0 if W >= 2 * H else 5.5
    fig, ax = plt.subplots(n + 1, 2, figsize=(width, 0.6 + (n + 1) * width / 2 * H / W * 1.1), squeeze=False)
    ax[0, 0].imshow(frame)
    ax[0, 0].set_title("training frame", fontsize=8)
    for a in ax.flat:
        a.set_xticks([])
        a.set_yticks([])
    vmax = max(p["vmax"] for p in panels)
    for r, p in enumerate(panels, 1):
        ax[r, 0].imshow(p["image"])
        ax[r, 0].set_title(f"{p['name']}: render", fontsize=8)
        ax[r, 1].imshow(p["speed_image"])
        ax[r, 1].set_title(f"|J_i qdot|, roughness {p['roughness']:.2f} px/s", fontsize=8)
    # the shared colour scale in the free top-right cell
    ax[0, 1].set_axis_off()
    cax = ax[0, 1].inset_axes((0.05, 0.7, 0.9, 0.14))
    cb = fig.colorbar(ScalarMappable(Normalize(0, vmax), "magma"), cax=cax, orientation="horizontal")
    cb.set_label("|J_i qdot| (px/s)", fontsize=7)
    cb.ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    with atomic_write(out_path) as tmp:
        fig.savefig(tmp, dpi=150, format="png")
    plt.close(fig)
    return Path(out_path)

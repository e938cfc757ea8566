"""The Stage-1 autoencoder: encoder + conditioned-Gaussian decoder, and its checkpoint (paper §3.2, App. C).

:class:`AutoEncoder` pairs the CpAE encoder (:mod:`lagsplat.models.encoder`)
with the conditioned-Gaussian decoder (:mod:`lagsplat.models.decoder`) at the
image size they were trained at; :func:`save_stage1` / :func:`load_stage1`
write and rebuild the ``stage1.pt`` checkpoint that
:mod:`lagsplat.train.stage1` trains. The latent here is the *raw* encoder
output ``z``; the chart (:mod:`lagsplat.chart`) whitens it to ``q``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch
from torch import Tensor, nn

from lagsplat.io.atomic import save_torch
from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.deformation import build_decoder
from lagsplat.models.encoder import CpAEEncoder

__all__ = ["AutoEncoder", "frames_to_tensor", "save_stage1", "load_stage1"]


class AutoEncoder(nn.Module):
    """Encoder + decoder pair with the image size they were trained at.

    Args:
        encoder: :class:`CpAEEncoder`.
        decoder: :class:`ConditionedGaussians`.
        height, width: training resolution in pixels.
    """

    def __init__(self, encoder: CpAEEncoder, decoder: ConditionedGaussians, height: int, width: int) -> None:
        super().__init__()
        self.encoder, self.decoder = encoder, decoder
        self.height, self.width = int(height), int(width)

    def encode(self, x: Tensor) -> Tensor:
        """``[B,3,H,W]`` -> raw latent ``z [B,d]``."""
        return self.encoder(x)

    def decode(self, z: Tensor, height: int | None = None, width: int | None = None) -> Tensor:
        """Raw latent ``z [B,d]`` -> ``[B,3,H,W]`` (training resolution by default)."""
        return self.decoder(z, height or self.height, width or self.width)

    @torch.no_grad()
    def encode_frames(self, frames: np.ndarray, batch: int = 128) -> Tensor:
        """Encode uint8 frames ``[T,H,W,3]`` to ``z [T,d]`` (eval mode, no grad)."""
        out = [self.encoder(frames_to_tensor(frames[i : i + batch])) for i in range(0, len(frames), batch)]
        return torch.cat(out)


def frames_to_tensor(frames: np.ndarray) -> Tensor:
    """uint8 ``[T,H,W,3]`` -> float32 ``[T,3,H,W]`` in [0, 1]."""
    return torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float().div_(255.0)


def save_stage1(path: str | Path, model: AutoEncoder, config: Mapping[str, Any], history: dict, d: int) -> Path:
    """Write ``stage1.pt`` atomically: weights, sizes, the decoder family and the config that made them."""
    dec = model.decoder
    return save_torch(
        path,
        {
            "encoder": model.encoder.state_dict(),
            "decoder": model.decoder.state_dict(),
            "d": d,
            "n_gaussians": model.decoder.K,
            "decoder_kind": dec.kind,
            "decoder_options": dec.options(),
            "height": model.height,
            "width": model.width,
            "encoder_channels": [m.out_channels for m in model.encoder.features if isinstance(m, nn.Conv2d)],
            "encoder_kernel": model.encoder.features[0].kernel_size[0],
            "config": dict(config),
            "history": history,
        },
    )


def load_stage1(path: str | Path) -> AutoEncoder:
    """Rebuild the :class:`AutoEncoder` saved by :func:`save_stage1` (eval mode).

    The decoder is of the family saved with it (``decoder_kind``; checkpoints
    without one hold the conditioned decoder of paper §3.2).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: naming the file, for an unknown decoder family.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: stage-1 checkpoint not found")
    ck = torch.load(path, map_location="cpu", weights_only=False)
    enc = CpAEEncoder(ck["d"], tuple(ck["encoder_channels"]), ck["encoder_kernel"])
    if "reference" in ck["encoder"]:
        enc.set_reference(ck["encoder"]["reference"])
    enc.load_state_dict(ck["encoder"])
    backend = ck["config"].get("backend", "auto") if isinstance(ck.get("config"), dict) else "auto"
    try:
        dec = build_decoder(ck.get("decoder_kind", "conditioned"), ck["n_gaussians"], ck["d"], backend=backend, **ck.get("decoder_options", {}))
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    dec.load_state_dict(ck["decoder"])
    return AutoEncoder(enc, dec, ck["height"], ck["width"]).eval()

"""Where training runs: ``device=auto|cpu|cuda`` (``conf/config.yaml``)."""

from __future__ import annotations

import torch

__all__ = ["resolve_device"]


def resolve_device(name: str) -> torch.device:
    """The torch device a training stage runs on.

    ``"cpu"`` (the default and the reference: every result of the project is
    produced and tested there), ``"cuda"`` (the first CUDA device; the
    rasteriser then uses gsplat's kernels when gsplat is installed, else the
    pure-torch tile rasteriser) or ``"auto"`` (``"cuda"`` when one is
    available, else ``"cpu"``).

    Raises:
        ValueError: on another name, or ``"cuda"`` where torch sees no CUDA device.
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cpu":
        return torch.device("cpu")
    if name == "cuda":
        if not torch.cuda.is_available():
            raise ValueError("device=cuda, but torch sees no CUDA device (a CPU build of torch, or no GPU); use device=cpu or device=auto")
        return torch.device("cuda")
    raise ValueError(f"device={name!r}: expected auto, cpu or cuda")

"""Weight averaging over the late epochs of a fit (stochastic weight averaging).

Izmailov et al., "Averaging Weights Leads to Wider Optima and Better
Generalization" (UAI 2018): the running mean of the weights an optimiser visits
after it has reached a basin generalises better than any one of them, because
the single iterate still wanders with the minibatch noise. The mean is kept by
:class:`torch.optim.swa_utils.AveragedModel` (parameters and buffers).

Used by :func:`lagsplat.train.stage2.train_stage2` when
``Stage2Config.average_from`` is set: the model at each selection point from
that fraction of the epochs on joins the mean (the gap diagnosis's refit sets
it, :mod:`lagsplat.diagnose.refit`).
"""

from __future__ import annotations

import torch
from torch.optim.swa_utils import AveragedModel

__all__ = ["WeightAverage"]


class WeightAverage:
    """Running mean of a model's weights over the epochs from ``start_epoch`` on.

    Args:
        start_epoch: the first epoch (0-based) whose weights join the mean; ``None``: averaging is off
            and :meth:`offer` does nothing.

    Attributes:
        epochs: the epochs averaged so far.
    """

    def __init__(self, start_epoch: float | None) -> None:
        self.start_epoch = start_epoch
        self.epochs: list[int] = []
        self._mean: AveragedModel | None = None

    def offer(self, model: torch.nn.Module, epoch: int) -> bool:
        """Add ``model``'s current weights to the mean if ``epoch >= start_epoch``; returns whether they were added."""
        if self.start_epoch is None or epoch < self.start_epoch:
            return False
        if self._mean is None:
            self._mean = AveragedModel(model, use_buffers=True)
        self._mean.update_parameters(model)
        self.epochs.append(int(epoch))
        return True

    def state_dict(self) -> dict[str, torch.Tensor] | None:
        """The averaged weights, as a state dict of the offered model (``None`` when nothing was averaged)."""
        return None if self._mean is None else self._mean.module.state_dict()

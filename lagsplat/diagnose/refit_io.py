"""The refit model on disk: written atomically by :func:`save_refit` and rebuilt by :func:`load_refit`.

Its file is the diagnosis artifact ``DIAGNOSIS_FILES["refit"]`` of
:mod:`lagsplat.artifacts`, which :func:`lagsplat.diagnose.report.diagnose_artifacts`
writes when a refit was made.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import torch
from torch import nn

from lagsplat.diagnose.effect_terms import term_from_spec
from lagsplat.diagnose.refit import RefitResult
from lagsplat.diagnose.refit_terms import RefitModel, ScaledTerm
from lagsplat.diagnose.terms import AugmentedLagrangian
from lagsplat.io.atomic import save_torch

__all__ = ["save_refit", "load_refit"]


def save_refit(path: str | Path, result: RefitResult, stage2_cfg: Any) -> Path:
    """Write the refit model atomically: base weights, term specs and state, delay, settings."""
    m = result.model
    base = m.base if isinstance(m, AugmentedLagrangian) else m
    return save_torch(path, {
        "base_state_dict": base.state_dict(), "terms": [t.storage() for t in getattr(m, "terms", [])],
        "state_dict": m.state_dict(), "time_channel": bool(getattr(m, "time_channel", False)),
        "delay_s": float(result.spec.delay_s), "config": dataclasses.asdict(stage2_cfg), "d": int(base.d),
        "n_u": int(getattr(base, "n_u", 0)), "effects": list(result.spec.effects), "history": result.history,
    })  # fmt: skip


def load_refit(path: str | Path, inertia: Any | None = None) -> tuple[nn.Module, dict]:
    """Rebuild a model saved by :func:`save_refit` (eval mode); ``(model, checkpoint)``.

    The model reads the chart ``model_chart(chart, ck["delay_s"], ck["time_channel"])``
    (:func:`~lagsplat.diagnose.refit_terms.model_chart`: the input delayed and / or the clip time appended).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        KeyError: if a term class is unknown.
    """
    from lagsplat.train.stage2 import Stage2Config

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: refit checkpoint not found")
    ck = torch.load(path, map_location="cpu", weights_only=False)
    cfg = Stage2Config.from_mapping(ck["config"])
    base = cfg.build(ck["d"], ck["n_u"], inertia)
    base.load_state_dict(ck["base_state_dict"])
    if not ck["terms"] and not ck["time_channel"]:
        return base.eval(), ck
    terms = [ScaledTerm(term_from_spec(dict(sp["inner"])), sp["scale"]) for sp in ck["terms"]]
    model = RefitModel(base, terms, time_channel=ck["time_channel"])
    model.load_state_dict(ck["state_dict"])
    return model.eval(), ck

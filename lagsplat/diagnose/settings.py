"""Settings of the diagnosis (``conf/config.yaml``, group ``diagnose``): plain dataclasses, importable without the
diagnosis's numerical modules (the configuration schema reads them at every stage's start-up)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

__all__ = ["WhereConfig", "RefitConfig", "DiagnoseConfig"]


@dataclass
class WhereConfig:
    """Settings of the localisation (``conf/config.yaml``, group ``diagnose.where``).

    Attributes:
        horizon_periods: length of each free rollout, natural periods.
        start_every_periods: spacing of the rollout starts, natural periods.
        sigma: Gaussian smoothing of the encoded trajectory before the initial
            state is read, frames (as :class:`lagsplat.evaluate.EvalConfig`).
        floor_factor: a frame is flagged when the rollout error (resp. the
            residual) exceeds this many times its floor.
        min_window_periods: flagged runs shorter than this are dropped, and runs
            closer than this are merged (natural periods).
        rest_radius: phase-portrait radius (units of ``S``) below which a sample is "near rest".
        turning_ratio: ``|y| / radius`` below which a sample is at a turning point.
        high_speed_quantile: quantile of ``|pdot|`` above which a sample is at high speed.
        n_image_frames: rollout frames rendered for the image maps (0: no image analysis).
        pixel_chunk: pixels per call of the compositing weights (memory bound).
        top_gaussians: Gaussians listed in the report.
        moving_fraction: a Gaussian *moves* when ``|J_i|_F`` (pixels per unit whitened
            ``q``) is at least this fraction of the 99th percentile over the Gaussians
            (trained decoders give background primitives small, non-zero ``J_i``).
    """

    horizon_periods: float = 1.0
    start_every_periods: float = 0.25
    sigma: float = 1.0
    floor_factor: float = 2.0
    min_window_periods: float = 0.25
    rest_radius: float = 0.2
    turning_ratio: float = 0.38
    high_speed_quantile: float = 0.75
    n_image_frames: int = 48
    pixel_chunk: int = 2048
    top_gaussians: int = 10
    moving_fraction: float = 0.1

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None) -> WhereConfig:
        """Build from a (Hydra) mapping; unknown keys raise ``KeyError``."""
        from lagsplat.train.config import dataclass_from_mapping

        return dataclass_from_mapping(cls, dict(m or {}), "diagnose.where")


@dataclass
class RefitConfig:
    """Refit settings (``conf/config.yaml``, group ``diagnose.refit``).

    Attributes:
        enabled: refit when an effect is found.
        init: ``"fitted"`` (fine-tune the fitted Lagrangian with the term) or ``"scratch"``.
        epochs: Stage-2 epochs of the fine-tune (``init="fitted"``); ``None`` keeps
            the Stage-2 setting (always the case for ``"scratch"``).
        lr: learning rate of the fine-tune (``None``: the Stage-2 one).
        control: also fine-tune without the term (same settings and seed).
        seed: RNG seed of the refit.
        floor_scale: energy-gauge factor ``g`` applied to the fitted model before the
            fine-tune (``s_M, s_V += log g``, term coefficients ``x g``), so that the fixed
            dissipation floor ``c0`` weighs ``g`` times less (paper App. C fixes it at a
            damping ratio ``stage2.zeta_floor`` of the training frequency, which can exceed
            the true damping once a dry friction or drag carries the decay). The damping
            the floor gives up moves into the learned dissipation (:func:`_gauged`), so the
            fine-tune starts from the fitted dynamics. ``1``: no change. Applied to the
            control too.
        choose: when several candidates with a Stage-2 remedy pass the significance
            rule, confirm the Delta-BIC winner by its refit's *training*-rollout error
            and fall back to the best rival whose refit beats the identified model
            (:func:`~lagsplat.diagnose.refit_choice.choose_by_refit`, the model selection of paper §3.3);
            ``False``: the Delta-BIC order decides alone.
    """

    enabled: bool = True
    init: Literal["fitted", "scratch"] = "fitted"
    epochs: int | None = 100
    lr: float | None = None
    control: bool = True
    seed: int = 0
    floor_scale: float = 4.0
    choose: bool = True

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None) -> RefitConfig:
        """Build from a (Hydra) mapping; unknown keys raise ``KeyError``."""
        from lagsplat.train.config import dataclass_from_mapping

        return dataclass_from_mapping(cls, dict(m or {}), "diagnose.refit")



@dataclass
class DiagnoseConfig:
    """Settings of the ``diagnose`` stage (``conf/config.yaml``, group ``diagnose``).

    Attributes:
        split: frames the diagnosis and the localisation read (``"train"``; the
            held-out frames are kept for the gap).
        sigma: residual smoothing, frames (``None``: automatic).
        select: keyword arguments of :func:`lagsplat.diagnose.select_effect`
            (``min_delta_bic``, ``min_r2``, ``min_cv_gain``, ``max_effects``, ...).
        where: :class:`~lagsplat.diagnose.where.WhereConfig`.
        refit: :class:`~lagsplat.diagnose.refit.RefitConfig`.
    """

    split: Literal["train", "held_out", "all"] = "train"
    sigma: float | None = None
    select: dict[str, Any] = field(default_factory=dict)
    where: WhereConfig = field(default_factory=WhereConfig)
    refit: RefitConfig = field(default_factory=RefitConfig)

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None) -> DiagnoseConfig:
        """Build from a (Hydra) mapping.

        Raises:
            KeyError: on an unknown key (in any sub-group).
        """
        m = dict(m or {})
        unknown = set(m) - {"split", "sigma", "select", "where", "refit"}
        if unknown:
            raise KeyError(f"unknown diagnose settings: {sorted(unknown)}")
        return cls(
            split=str(m.get("split", "train")), sigma=None if m.get("sigma") is None else float(m["sigma"]),
            select=dict(m.get("select") or {}), where=WhereConfig.from_mapping(m.get("where")),
            refit=RefitConfig.from_mapping(m.get("refit")),
        )  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        """Plain record (saved in ``report.json``)."""
        return {"split": self.split, "sigma": self.sigma, "select": dict(self.select), "where": asdict(self.where), "refit": asdict(self.refit)}

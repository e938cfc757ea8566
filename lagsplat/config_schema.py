"""Typed configuration: one dataclass per group of ``conf/``, checked at start-up.

Every group of ``conf/config.yaml`` and the ``system`` group of
``conf/system/<name>.yaml`` has a dataclass: the stages' own settings classes
(:class:`~lagsplat.train.stage1.Stage1Config`, :class:`~lagsplat.train.stage2.Stage2Config`,
:class:`~lagsplat.evaluate.paper.EvalConfig`, ...) and the ones below for the
groups without one. They are registered in Hydra's ConfigStore (group
``schema``) and are the one source of defaults: ``tests/test_config_schema.py``
checks that the YAML repeats no default with another value.

:func:`validate_config` reads a composed configuration against them before any
work: an unknown key, a value of the wrong type, a choice outside its
``Literal`` and a number outside its range each stop the run with one line
naming the key and the value, e.g. ``stage1.steps=-5: must be >= 1``.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Literal, Mapping, Optional, Union

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, ListConfig, OmegaConf

from lagsplat.artifacts import Artifacts
from lagsplat.diagnose.refit import RefitConfig
from lagsplat.diagnose.report import DiagnoseConfig
from lagsplat.diagnose.where import WhereConfig
from lagsplat.evaluate.krauss import KraussEvalConfig
from lagsplat.evaluate.paper import EvalConfig
from lagsplat.force_checks import ForceCheckConfig
from lagsplat.train.stage1 import Stage1Config
from lagsplat.train.stage2 import Stage2Config

__all__ = ["ConfigError", "validate_config", "SCHEMAS", "CHECKS", "SystemConfig", "SourceConfig", "ViewConfig", "ChartConfig"]


class ConfigError(ValueError):
    """A configuration value that no run may use; the message names the key and the value."""


@dataclass
class SourceConfig:
    """Where a system's clip comes from (``system.source`` or one entry of ``system.sources``; :mod:`lagsplat.ingest`)."""

    file: Optional[str] = None  # file name under raw_dir (the download rule's target)
    path: Optional[str] = None  # video, image folder, .npz or .mcap
    url: Optional[str] = None
    sha256: Optional[str] = None
    member: Optional[str] = None  # a file inside a zip archive (lagsplat.io.zenodo)
    archive_file: Optional[str] = None
    fps: Optional[float] = None  # true capture rate, Hz
    dt: Optional[float] = None  # frame interval, s (.npz)
    image_topic: Optional[str] = None  # .mcap
    actuation: Optional[list] = None  # .npz keys or .mcap topics
    max_fps: Optional[float] = None
    jitter_tol: Optional[float] = None
    synth: Optional[str] = None  # a procedural clip of lagsplat.synth
    params: Optional[dict] = None
    generator: Optional[dict] = None  # the simulated soft robot: how the download rule makes the file (lagsplat.synth.continuum_robot)
    held_out: bool = False  # multi-recording systems: kept out of training
    frames: Optional[list] = None


@dataclass
class SplitConfig:
    """The contiguous train / held-out split (``system.split``)."""

    train_fraction: float = 0.8


@dataclass
class SystemConfig:
    """One system (``conf/system/<name>.yaml``, group ``system``)."""

    name: str = "?"
    title: Optional[str] = None
    d: int = 1  # latent dimension = degrees of freedom of the chart
    provenance: str = ""
    protocol: Literal["default", "paper", "krauss"] = "default"
    data: Optional[Literal["real", "surrogate", "synthetic"]] = None
    truth: Optional[str] = None  # surrogate soft robot: the simulator's sidecar JSON
    segments: Optional[int] = None
    source: Optional[SourceConfig] = None
    sources: Optional[list] = None
    frames: Optional[list] = None  # [start, stop) of source frames
    crop: Optional[list] = None  # x0 y0 x1 y1, native pixels
    resize: Optional[list] = None  # W H
    split: SplitConfig = field(default_factory=SplitConfig)


@dataclass
class ChartConfig:
    """The chart (``chart`` group; paper §3.2 "Reading the chart", :func:`lagsplat.chart.build_chart`)."""

    n_metric_samples: int = 64
    rho: float = 0.01
    refine_iters: int = 0


@dataclass
class ViewConfig:
    """The interactive viewer (``view`` group; :mod:`lagsplat.viewer`)."""

    port: int = 8765
    sigma: float = 2.0
    force_scale: Any = "auto"  # "auto" or a positive number
    kappa: float = 1.0
    initial: Literal["held_out", "rest"] = "held_out"
    render_scale: float = 1.0
    image_format: Literal["png", "jpeg"] = "png"
    max_substeps: int = 8
    open_browser: bool = False
    max_seconds: Optional[float] = None


@dataclass
class DownloadConfig:
    """The download stage (``download`` group)."""

    file: Optional[str] = None
    archive: Optional[str] = None


@dataclass
class TableConfig:
    """``python -m lagsplat table`` (``table`` group)."""

    name: str = "physical"
    systems: list = field(default_factory=lambda: ["toy", "oscillating_cart", "red_apple_pendulum"])


@dataclass
class SeedTableConfig:
    """``python -m lagsplat seed_table`` (``seed_table`` group)."""

    seeds: list = field(default_factory=lambda: [0, 1, 2])
    dir: str = "seeds"


@dataclass
class KraussTableConfig:
    """``python -m lagsplat krauss_table`` (``krauss_table`` group)."""

    name: str = "krauss"
    one_segment: Optional[str] = "krauss_1seg"
    two_segments: Optional[str] = "krauss_2seg"
    ablation: list = field(default_factory=lambda: ["mass_decoder", "mass_constant"])


ArtifactsConfig = dataclasses.make_dataclass(
    "ArtifactsConfig", [(n, Optional[str], None) for n in Artifacts.names()], namespace={"__doc__": "Per-artifact path overrides (``artifacts`` group)."}
)


@dataclass
class RunConfig:
    """The top level of ``conf/config.yaml``."""

    results_dir: str = "results"
    raw_dir: str = "data/raw"
    seed: int = 0
    threads: int = 0
    device: Literal["cpu", "cuda", "auto"] = "cpu"
    progress: bool = True
    log: Optional[str] = None
    variant: Optional[str] = None
    variants: dict = field(default_factory=dict)
    ablation: str = "inertia"
    ablations: dict = field(default_factory=dict)


SCHEMAS: dict[str, type] = {
    "system": SystemConfig,
    "download": DownloadConfig,
    "artifacts": ArtifactsConfig,
    "stage1": Stage1Config,
    "chart": ChartConfig,
    "stage2": Stage2Config,
    "evaluate": EvalConfig,
    "krauss_eval": KraussEvalConfig,
    "forces": ForceCheckConfig,
    "diagnose": DiagnoseConfig,
    "view": ViewConfig,
    "table": TableConfig,
    "seed_table": SeedTableConfig,
    "krauss_table": KraussTableConfig,
}
"""Group name -> its dataclass; the top-level keys are :class:`RunConfig`'s."""

_POS, _NONNEG, _UNIT, _OPEN_UNIT = (">", 0), (">=", 0), ("[]", (0, 1)), ("(]", (0, 1))
CHECKS: dict[str, Any] = {
    "seed": _NONNEG, "threads": _NONNEG,
    "system.d": (">=", 1), "system.split.train_fraction": _OPEN_UNIT, "system.source.fps": _POS, "system.source.dt": _POS,
    "stage1.n_gaussians": (">=", 1), "stage1.steps": (">=", 1), "stage1.batch": (">=", 1),
    "stage1.lr_encoder": _POS, "stage1.lr_decoder": _POS, "stage1.sigma_xy": _POS, "stage1.sigma_q_floor": _POS,
    "stage1.w_l1": _NONNEG, "stage1.w_ssim": _NONNEG, "stage1.w_aniso": _NONNEG, "stage1.w_nonlocal": _NONNEG,
    "stage1.w_static": _NONNEG, "stage1.static_margin": _POS, "stage1.ssim_window": (">=", 1),
    "stage1.aniso_max_ratio": (">=", 1), "stage1.alpha_dead": _UNIT, "stage1.recycle_every": (">=", 1),
    "stage1.recycle_warmup": _NONNEG, "stage1.grad_clip": _POS, "stage1.encoder_kernel": (">=", 1), "stage1.threads": _NONNEG,
    "stage1.backend": ("in", ("auto", "cpu", "torch", "dense", "gsplat")),
    "chart.n_metric_samples": (">=", 1), "chart.rho": _POS, "chart.refine_iters": _NONNEG,
    "stage2.mass": ("in", ("scalar", "constant", "learned", "decoder")), "stage2.potential": ("in", ("convex", "invex")),
    "stage2.c0": _NONNEG, "stage2.eps_V": _NONNEG, "stage2.zeta_floor": _NONNEG, "stage2.stride": (">=", 1), "stage2.sigma": _NONNEG,
    "stage2.w_q": _NONNEG, "stage2.w_v": _NONNEG, "stage2.lr": _POS, "stage2.epochs": (">=", 1), "stage2.batch": (">=", 1),
    "stage2.windows_per_epoch": (">=", 1), "stage2.grad_clip": _POS, "stage2.select_every": (">=", 1),
    "stage2.select_windows": (">=", 1), "stage2.select_periods": _POS,
    "evaluate.n_windows": (">=", 1), "evaluate.seed": _NONNEG, "evaluate.n_periods": _POS, "evaluate.sigma": _NONNEG,
    "evaluate.freq_window_periods": _POS, "evaluate.min_amplitude": _NONNEG, "evaluate.render_batch": (">=", 1),
    "forces.sigma": _POS, "forces.min_transmittance": _UNIT, "forces.grid": (">=", 1), "forces.moving_frac": _UNIT,
    "forces.static_factor": _POS, "forces.target_dq": _POS, "forces.background_ratio": _POS,
    "diagnose.split": ("in", ("train", "held_out", "all")), "diagnose.refit.init": ("in", ("fitted", "scratch")),
    "diagnose.refit.floor_scale": _POS, "diagnose.where.n_image_frames": _NONNEG, "diagnose.where.horizon_periods": _POS,
    "view.port": ("[]", (0, 65535)), "view.sigma": _POS, "view.kappa": _POS, "view.render_scale": _POS, "view.max_substeps": (">=", 1),
}  # fmt: skip
"""Dotted key -> constraint beyond the type: ``(">", x)``, ``(">=", x)``, ``("[]", (a, b))``, ``("(]", (a, b))`` or ``("in", choices)``."""


def _plain(node: Any) -> Any:
    return OmegaConf.to_container(node, resolve=True) if isinstance(node, (DictConfig, ListConfig)) else node


def _bad(key: str, value: Any, why: str) -> ConfigError:
    return ConfigError(f"{key}={value!r}: {why}")


def _check_type(key: str, value: Any, tp: Any) -> None:
    """Raise :class:`ConfigError` if ``value`` does not fit the annotation ``tp`` (dataclasses are walked)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any:
        return
    if origin is Union or origin is types.UnionType:
        if value is None and type(None) in args:
            return
        errors = []
        for a in (a for a in args if a is not type(None)):
            try:
                return _check_type(key, value, a)
            except ConfigError as e:
                errors.append(e)
        raise errors[0] if errors else _bad(key, value, "must be null")
    if value is None:
        raise _bad(key, value, f"must be set ({getattr(tp, '__name__', tp)})")
    if origin is Literal:
        if value not in args:
            raise _bad(key, value, f"must be one of {list(args)}")
        return
    if dataclasses.is_dataclass(tp):
        _check_group(key, value, tp)
        return
    if tp is bool or tp is str:
        if not isinstance(value, tp):
            raise _bad(key, value, f"must be a {'boolean (true / false)' if tp is bool else 'string'}")
        return
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _bad(key, value, "must be an integer")
        return
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _bad(key, value, "must be a finite number")
        return
    if tp in (list, tuple) or origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise _bad(key, value, "must be a list")
        if args and args[-1] is not Ellipsis and origin is tuple and len(args) != len(value):
            raise _bad(key, value, f"must be a list of {len(args)} values")
        item = args[0] if args else Any
        for i, v in enumerate(value):
            _check_type(f"{key}[{i}]", v, item)
        return
    if tp is dict or origin is dict:
        if not isinstance(value, Mapping):
            raise _bad(key, value, "must be a mapping")


def _check_group(prefix: str, values: Any, cls: type) -> None:
    if not isinstance(values, Mapping):
        raise _bad(prefix, values, "must be a mapping")
    hints = typing.get_type_hints(cls)
    known = [f.name for f in dataclasses.fields(cls)]
    for k, v in values.items():
        key = f"{prefix}.{k}"
        if k not in hints:
            raise ConfigError(f"{key}: unknown key (known in {prefix}: {', '.join(known)})")
        _check_type(key, v, hints[k])


def _check_constraint(key: str, value: Any, rule: tuple) -> None:
    op, arg = rule
    if value is None:
        return
    if op == "in":
        if value not in arg:
            raise _bad(key, value, f"must be one of {list(arg)}")
        return
    if op == ">" and not value > arg:
        raise _bad(key, value, f"must be > {arg}")
    if op == ">=" and not value >= arg:
        raise _bad(key, value, f"must be >= {arg}")
    if op == "[]" and not arg[0] <= value <= arg[1]:
        raise _bad(key, value, f"must be in [{arg[0]}, {arg[1]}]")
    if op == "(]" and not arg[0] < value <= arg[1]:
        raise _bad(key, value, f"must be in ({arg[0]}, {arg[1]}]")


def _lookup(tree: Mapping, dotted: str) -> tuple[bool, Any]:
    node: Any = tree
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return False, None
        node = node[part]
    return True, node


def validate_config(cfg: DictConfig | Mapping[str, Any]) -> None:
    """Check a composed configuration against :data:`SCHEMAS`, :class:`RunConfig` and :data:`CHECKS`.

    Raises:
        ConfigError: one line naming the first offending key and its value.
    """
    tree = _plain(cfg) if isinstance(cfg, (DictConfig, ListConfig)) else dict(cfg)
    run_hints = typing.get_type_hints(RunConfig)
    for k, v in tree.items():
        if k in SCHEMAS:
            if v is not None:
                _check_group(k, v, SCHEMAS[k])
        elif k in run_hints:
            _check_type(k, v, run_hints[k])
        else:
            raise ConfigError(f"{k}: unknown key (groups: {', '.join(SCHEMAS)}; top level: {', '.join(run_hints)})")
    for entry_i, src in enumerate((tree.get("system") or {}).get("sources") or []):
        _check_group(f"system.sources[{entry_i}]", src, SourceConfig)
    for dotted, rule in CHECKS.items():
        present, value = _lookup(tree, dotted)
        if present:
            _check_constraint(dotted, value, rule)
    fs = (tree.get("view") or {}).get("force_scale", "auto")
    if fs not in (None, "auto") and not (isinstance(fs, (int, float)) and not isinstance(fs, bool) and fs > 0):
        raise _bad("view.force_scale", fs, "must be auto or a positive number")
    v = tree.get("variant")
    if v is not None and v not in (tree.get("variants") or {}):
        raise _bad("variant", v, f"must be one of {sorted(tree.get('variants') or {})} (conf/config.yaml, key variants)")


def _omegaconf_type(tp: Any) -> Any:
    """The nearest annotation OmegaConf's structured configs accept (it has no ``Literal``: the choices
    are checked by :func:`validate_config`)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        return str
    if origin is Union or origin is types.UnionType:
        inner = [a for a in args if a is not type(None)]
        return Optional[_omegaconf_type(inner[0])] if len(inner) == 1 else Any
    if tp in (list, tuple) or origin in (list, tuple):
        return typing.List[Any]
    if tp is dict or origin is dict:
        return typing.Dict[str, Any]
    return tp


def structured_node(cls: type) -> type:
    """``cls`` as a dataclass OmegaConf can store (same fields and defaults, :func:`_omegaconf_type` annotations)."""
    hints = typing.get_type_hints(cls)
    specs = []
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            node = structured_node(hints[f.name])
            specs.append((f.name, node, field(default_factory=node)))
            continue
        tp = _omegaconf_type(hints[f.name])
        if f.default is not dataclasses.MISSING:
            d = list(f.default) if isinstance(f.default, tuple) else f.default
            specs.append((f.name, tp, field(default_factory=(lambda v=d: list(v))) if isinstance(d, list) else d))
        else:
            specs.append((f.name, tp, field(default_factory=f.default_factory)))
    return dataclasses.make_dataclass(f"{cls.__name__}Node", specs)


def register_schemas() -> None:
    """Register every group's dataclass in Hydra's ConfigStore, group ``schema`` (``schema/<group>``, ``schema/run``)."""
    cs = ConfigStore.instance()
    cs.store(group="schema", name="run", node=structured_node(RunConfig))
    for name, cls in SCHEMAS.items():
        cs.store(group="schema", name=name, node=structured_node(cls))


# the where / refit groups are nested in diagnose; named here so that the registry lists every settings class
NESTED = {"diagnose.where": WhereConfig, "diagnose.refit": RefitConfig}

"""Start-up checks of a composed configuration against the typed schema (:mod:`lagsplat.config_schema`).

:func:`validate_config` reads a composed configuration before any work.
Choices are the ``Literal`` annotations of the schema's dataclasses; ranges are
:data:`CHECKS`. An unknown key, a value of the wrong type, a choice outside its
set and a number outside its range each stop the run with one line naming the
key and the value, e.g. ``stage1.steps=-5: must be a positive integer``.
:func:`explain_compose_error` turns Hydra's composition errors (an unknown
group option, a malformed override) into such a line.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Mapping, Optional, Union

from omegaconf import DictConfig, ListConfig, OmegaConf

from lagsplat.cli_common import split_variant
from lagsplat.config_schema import SCHEMAS, RunConfig

__all__ = ["ConfigError", "Bound", "CHECKS", "validate_config", "explain_compose_error"]


class ConfigError(ValueError):
    """A configuration value that no run may use; the message (one line) names the key and the value."""


# ----------------------------------------------------------------------------- ranges
@dataclass(frozen=True)
class Bound:
    """The range a number must lie in, and how the error says it (``must be <words>``).

    Attributes:
        lo, hi: bounds (``None``: unbounded).
        lo_open, hi_open: the bound itself is excluded.
        words: the range in words, e.g. ``"a positive integer"``.
    """

    lo: Optional[float] = None
    hi: Optional[float] = None
    lo_open: bool = False
    hi_open: bool = False
    words: str = ""

    def admits(self, x: float) -> bool:
        """Whether the number ``x`` lies in the range."""
        if self.lo is not None and (x <= self.lo if self.lo_open else x < self.lo):
            return False
        return not (self.hi is not None and (x >= self.hi if self.hi_open else x > self.hi))


POSITIVE_INT = Bound(1, words="a positive integer")
COUNT = Bound(0, words="an integer >= 0")
POSITIVE = Bound(0, lo_open=True, words="a positive number")
NON_NEGATIVE = Bound(0, words="a number >= 0")
FRACTION = Bound(0, 1, words="in [0, 1]")
OPEN_FRACTION = Bound(0, 1, lo_open=True, words="in (0, 1]")

CHECKS: dict[str, Bound] = {
    "seed": COUNT, "threads": COUNT, "ablation_seeds[]": COUNT,
    # system (lagsplat.ingest); system.source.<key> rules hold for every system.sources entry too
    "system.d": POSITIVE_INT, "system.segments": POSITIVE_INT, "system.split.train_fraction": OPEN_FRACTION,
    "system.frames[]": COUNT, "system.crop[]": COUNT, "system.resize[]": POSITIVE_INT,
    "system.source.fps": POSITIVE, "system.source.dt": POSITIVE, "system.source.max_fps": POSITIVE,
    "system.source.jitter_tol": NON_NEGATIVE, "system.source.frames[]": COUNT,
    "system.scale.points[]": NON_NEGATIVE, "system.scale.metres": POSITIVE, "system.scale.pendulum_length_m": POSITIVE,
    "system.views.fps": POSITIVE, "system.views.holdout[]": COUNT, "system.views.n_views": POSITIVE_INT,
    "system.views.angle_deg": Bound(0, 90, lo_open=True, hi_open=True, words="in (0, 90) degrees"),
    # stage1 (Stage1Config)
    "stage1.n_gaussians": POSITIVE_INT, "stage1.steps": POSITIVE_INT, "stage1.batch": POSITIVE_INT,
    "stage1.lr_encoder": POSITIVE, "stage1.lr_decoder": POSITIVE, "stage1.w_l1": NON_NEGATIVE, "stage1.w_ssim": NON_NEGATIVE,
    "stage1.w_aniso": NON_NEGATIVE, "stage1.w_nonlocal": NON_NEGATIVE, "stage1.w_static": NON_NEGATIVE,
    "stage1.static_margin": POSITIVE, "stage1.ssim_window": POSITIVE_INT, "stage1.aniso_max_ratio": Bound(1, words="a number >= 1"),
    "stage1.sigma_xy": POSITIVE, "stage1.sigma_q_floor": POSITIVE, "stage1.alpha_dead": FRACTION,
    "stage1.recycle_every": POSITIVE_INT, "stage1.recycle_warmup": COUNT, "stage1.grad_clip": POSITIVE,
    "stage1.encoder_channels[]": POSITIVE_INT, "stage1.encoder_kernel": POSITIVE_INT, "stage1.background[]": FRACTION,
    "stage1.threads": COUNT, "stage1.retries": COUNT, "stage1.w_motion_init": NON_NEGATIVE, "stage1.split_share": FRACTION,
    "stage1.w_temporal": NON_NEGATIVE, "stage1.plateau_patience": COUNT, "stage1.plateau_tol": NON_NEGATIVE, "stage1.max_minutes": POSITIVE,
    "stage1.deform_hidden[]": POSITIVE_INT, "stage1.deform_freqs": COUNT, "stage1.w_center": NON_NEGATIVE,
    "stage1.anchor_steps": COUNT, "stage1.anchor_share": FRACTION,
    "render.n_cameras": POSITIVE_INT, "render.size[]": POSITIVE_INT, "render.frame": COUNT, "render.rollout_s": NON_NEGATIVE,
    "render.fps": POSITIVE,
    "stage1.w_views": NON_NEGATIVE, "stage1.w_depth": NON_NEGATIVE, "stage1.views_per_step": POSITIVE_INT, "stage1.depth_range[]": POSITIVE,
    # chart
    "chart.n_metric_samples": POSITIVE_INT, "chart.rho": POSITIVE, "chart.refine_iters": COUNT,
    # stage2 (Stage2Config)
    "stage2.c0": NON_NEGATIVE, "stage2.dissipation_init": NON_NEGATIVE, "stage2.hidden[]": POSITIVE_INT,
    "stage2.eps_V": NON_NEGATIVE, "stage2.zeta_floor": NON_NEGATIVE, "stage2.stride": POSITIVE_INT, "stage2.max_step_phase": NON_NEGATIVE, "stage2.sigma": NON_NEGATIVE,
    "stage2.w_q": NON_NEGATIVE, "stage2.w_v": NON_NEGATIVE, "stage2.lr": POSITIVE, "stage2.lr_potential_input": POSITIVE, "stage2.w_actuation_linear": NON_NEGATIVE, "stage2.rollout_steps": POSITIVE_INT, "stage2.potential_kinks": NON_NEGATIVE, "stage2.potential_kinks_alternatives[]": NON_NEGATIVE, "stage2.epochs": POSITIVE_INT,
    "stage2.batch": POSITIVE_INT, "stage2.windows_per_epoch": POSITIVE_INT, "stage2.grad_clip": POSITIVE,
    "stage2.select_every": POSITIVE_INT, "stage2.select_from": NON_NEGATIVE, "stage2.select_windows": POSITIVE_INT, "stage2.select_periods": POSITIVE,
    # evaluate (EvalConfig)
    "evaluate.n_windows": POSITIVE_INT, "evaluate.seed": COUNT, "evaluate.n_periods": POSITIVE, "evaluate.sigma": NON_NEGATIVE,
    "evaluate.freq_window_periods": POSITIVE, "evaluate.min_amplitude": NON_NEGATIVE, "evaluate.render_batch": POSITIVE_INT,
    # krauss_eval (KraussEvalConfig)
    "krauss_eval.horizon_s": POSITIVE, "krauss_eval.n_windows": POSITIVE_INT, "krauss_eval.seed": COUNT,
    "krauss_eval.skip_s": NON_NEGATIVE, "krauss_eval.sigma": NON_NEGATIVE, "krauss_eval.sigma_pressure": NON_NEGATIVE,
    "krauss_eval.ae_frames": POSITIVE_INT, "krauss_eval.flat_step_tol": NON_NEGATIVE, "krauss_eval.flat_total_tol": NON_NEGATIVE,
    "krauss_eval.min_flat_s": POSITIVE, "krauss_eval.max_intervals": POSITIVE_INT, "krauss_eval.freq_window_periods": POSITIVE,
    "krauss_eval.min_window": POSITIVE_INT, "krauss_eval.min_amplitude": NON_NEGATIVE, "krauss_eval.diverge_factor": POSITIVE,
    "krauss_eval.cycle_periods": POSITIVE, "krauss_eval.period_s": POSITIVE, "krauss_eval.render_batch": POSITIVE_INT,
    # forces (ForceCheckConfig)
    "forces.sigma": POSITIVE, "forces.min_transmittance": FRACTION, "forces.grid": POSITIVE_INT, "forces.moving_frac": FRACTION,
    "forces.static_factor": POSITIVE, "forces.target_dq": POSITIVE, "forces.background_ratio": POSITIVE, "forces.seed": COUNT,
    # diagnose (DiagnoseConfig, WhereConfig, RefitConfig)
    "diagnose.sigma": POSITIVE,
    "diagnose.where.horizon_periods": POSITIVE, "diagnose.where.start_every_periods": POSITIVE, "diagnose.where.sigma": NON_NEGATIVE,
    "diagnose.where.floor_factor": POSITIVE, "diagnose.where.min_window_periods": NON_NEGATIVE, "diagnose.where.rest_radius": POSITIVE,
    "diagnose.where.turning_ratio": POSITIVE, "diagnose.where.high_speed_quantile": FRACTION, "diagnose.where.n_image_frames": COUNT,
    "diagnose.where.pixel_chunk": POSITIVE_INT, "diagnose.where.top_gaussians": COUNT, "diagnose.where.moving_fraction": FRACTION,
    "diagnose.refit.epochs": POSITIVE_INT, "diagnose.refit.lr": POSITIVE, "diagnose.refit.seed": COUNT, "diagnose.refit.floor_scale": POSITIVE,
    # extrapolation (ExtrapolationConfig)
    "extrapolation.long_s": POSITIVE, "extrapolation.figure_s": POSITIVE, "extrapolation.sigma": NON_NEGATIVE, "extrapolation.render_batch": POSITIVE_INT,
    # robot_figures (RobotFigureConfig)
    "robot_figures.rollout_s": POSITIVE, "robot_figures.size": POSITIVE_INT, "robot_figures.sigma": NON_NEGATIVE,
    "robot_figures.brush_sigma": POSITIVE, "robot_figures.displacement": POSITIVE,
    # deformation (DeformationCompareConfig)
    "deformation.k_neighbours": POSITIVE_INT, "deformation.min_coverage": NON_NEGATIVE, "deformation.batch": POSITIVE_INT,
    # gp2d (GP2DConfig; 0 = the size rule)
    "gp2d.n_gaussians": COUNT, "gp2d.n_keypoints": COUNT, "gp2d.k_neighbours": COUNT, "gp2d.feature_dim": POSITIVE_INT, "gp2d.hidden[]": POSITIVE_INT,
    "gp2d.iterations": COUNT, "gp2d.frames_per_step": POSITIVE_INT, "gp2d.gcn_history": POSITIVE_INT, "gp2d.gcn_stages": COUNT,
    "gp2d.gcn_hidden": POSITIVE_INT, "gp2d.gcn_epochs": POSITIVE_INT, "gp2d.gcn_lr": POSITIVE, "gp2d.gcn_lr_min": POSITIVE, "gp2d.gcn_batch": POSITIVE_INT, "gp2d.gcn_max_steps": COUNT,
    # view (ViewConfig)
    "view.port": Bound(0, 65535, words="a port number in [0, 65535]"), "view.sigma": POSITIVE, "view.force_scale": POSITIVE,
    "view.kappa": POSITIVE, "view.render_scale": POSITIVE, "view.max_substeps": POSITIVE_INT, "view.max_seconds": POSITIVE, "view.force_3d": POSITIVE,
    # tables
    "seed_table.seeds[]": COUNT,
}  # fmt: skip
"""Dotted key -> the range of its number (``key[]``: of every item of the list); a ``None`` or a
non-number (``view.force_scale=auto``) is left to the type check."""


# ----------------------------------------------------------------------------- checking
def _bad(key: str, value: Any, why: str) -> ConfigError:
    return ConfigError(f"{key}={_show(value)}: {why}")


def _show(value: Any) -> str:
    """A value as the command line spells it (``null``, ``true``, ``[1, 2]``, ``abc``)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k}: {_show(v)}" for k, v in value.items()) + "}"
    return str(value)


def _describe(tp: Any) -> str:
    """An annotation in words (for an error message)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        return str(args[0]) if len(args) == 1 else "one of " + ", ".join(map(str, args))
    if origin is Union or origin is types.UnionType:
        return " or ".join("null" if a is type(None) else _describe(a) for a in args)
    names = {bool: "true or false", int: "an integer", float: "a number", str: "a string", dict: "a mapping", Any: "anything"}
    if tp in names:
        return names[tp]
    if dataclasses.is_dataclass(tp) or origin is dict:
        return "a mapping"
    return "a list"


def _check_type(key: str, value: Any, tp: Any) -> None:
    """Raise :class:`ConfigError` if ``value`` does not fit the annotation ``tp`` (dataclasses are walked)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any:
        return
    if origin is Union or origin is types.UnionType:
        if value is None and type(None) in args:
            return
        inner = [a for a in args if a is not type(None)]
        if isinstance(value, Mapping):
            fits = [a for a in inner if dataclasses.is_dataclass(a)]
        elif isinstance(value, (list, tuple)):  # e.g. crop: auto or [x0, y0, x1, y1]: the list's own error
            fits = [a for a in inner if a in (list, tuple) or typing.get_origin(a) in (list, tuple, Sequence)]
        else:
            fits = []
        if len(inner) == 1 or fits:  # one candidate: its own (more precise) error
            return _check_type(key, value, (fits or inner)[0])
        for a in inner:
            try:
                return _check_type(key, value, a)
            except ConfigError:
                pass
        raise _bad(key, value, f"must be {_describe(tp)}")
    if value is None:
        raise _bad(key, value, f"must be {_describe(tp)}, not null")
    if origin is Literal:
        if value not in args:
            raise _bad(key, value, f"must be one of {', '.join(map(str, args))}")
        return
    if dataclasses.is_dataclass(tp):
        _check_group(key, value, tp)
        return
    if tp is bool or tp is str:
        if not isinstance(value, tp):
            raise _bad(key, value, f"must be {_describe(tp)}")
        return
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _bad(key, value, "must be an integer")
        return
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _bad(key, value, "must be a finite number")
        return
    if tp in (list, tuple) or origin in (list, tuple, Sequence):
        if not isinstance(value, (list, tuple)):
            raise _bad(key, value, "must be a list")
        if origin is tuple and args and args[-1] is not Ellipsis and len(args) != len(value):
            raise _bad(key, value, f"must be a list of {len(args)} values")
        for i, v in enumerate(value):
            _check_type(f"{key}[{i}]", v, args[0] if args else Any)
        return
    if tp is dict or origin is dict:
        if not isinstance(value, Mapping):
            raise _bad(key, value, "must be a mapping")
        for k, v in value.items():
            _check_type(f"{key}.{k}", v, args[1] if len(args) == 2 else Any)


def _check_group(prefix: str, values: Any, cls: type) -> None:
    """Every key of ``values`` is a field of ``cls`` and fits its annotation."""
    if not isinstance(values, Mapping):
        raise _bad(prefix, values, "must be a mapping")
    hints = typing.get_type_hints(cls)
    for k, v in values.items():
        if k not in hints:
            known = ", ".join(f.name for f in dataclasses.fields(cls))
            raise _bad(f"{prefix}.{k}", v, f"unknown key (known in {prefix.split('[')[0]}: {known})")
        _check_type(f"{prefix}.{k}", v, hints[k])


def _check_number(key: str, value: Any, bound: Bound) -> None:
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if not bound.admits(value):
        raise _bad(key, value, f"must be {bound.words}")


def _check_ranges(tree: Mapping, prefix: str = "") -> None:
    """Apply :data:`CHECKS` to the keys present in ``tree`` (named ``prefix`` + key in the errors)."""
    sources = ((tree.get("system") or {}).get("sources") or []) if isinstance(tree.get("system"), Mapping) else []
    for dotted, bound in CHECKS.items():
        items = dotted.endswith("[]")
        path = dotted[:-2] if items else dotted
        places = [(path, _lookup(tree, path))]
        if path.startswith("system.source."):  # the same rules for every entry of system.sources
            rest = path[len("system.source."):]
            places += [(f"system.sources[{i}].{rest}", _lookup(e, rest)) for i, e in enumerate(sources) if isinstance(e, Mapping)]
        for key, (present, value) in places:
            if not present:
                continue
            if items and isinstance(value, (list, tuple)):
                for i, v in enumerate(value):
                    _check_number(f"{prefix}{key}[{i}]", v, bound)
            elif not items:
                _check_number(prefix + key, value, bound)


def _lookup(tree: Any, dotted: str) -> tuple[bool, Any]:
    node: Any = tree
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return False, None
        node = node[part]
    return True, node


def _check_tree(tree: Mapping, prefix: str = "") -> None:
    """Keys, types and ranges of a configuration tree (the whole run, or a variant's delta)."""
    run_hints = typing.get_type_hints(RunConfig)
    for k, v in tree.items():
        if k in SCHEMAS:
            if v is not None:
                _check_group(prefix + k, v, SCHEMAS[k])
        elif k in run_hints:
            _check_type(prefix + k, v, run_hints[k])
        else:
            raise _bad(prefix + k, v, f"unknown key (groups: {', '.join(SCHEMAS)}; top level: {', '.join(run_hints)})")
    _check_ranges(tree, prefix)
    _check_select(tree, prefix)


def _check_select(tree: Mapping, prefix: str) -> None:
    """``diagnose.select``: keyword arguments of :func:`lagsplat.diagnose.select_effect`, checked against its signature."""
    sel = (tree.get("diagnose") or {}).get("select") if isinstance(tree.get("diagnose"), Mapping) else None
    if not sel:
        return
    from lagsplat.diagnose import select_effect

    params = [n for n, p in inspect.signature(select_effect).parameters.items() if n != "res" and p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)]
    try:
        hints = typing.get_type_hints(select_effect)
    except (NameError, TypeError):  # an annotation that does not resolve: the keys are still checked
        hints = {}
    for k, v in sel.items():
        key = f"{prefix}diagnose.select.{k}"
        if k not in params:
            raise _bad(key, v, f"unknown key (select_effect's settings: {', '.join(params)})")
        if k in hints:
            _check_type(key, v, hints[k])


def validate_config(cfg: DictConfig | Mapping[str, Any]) -> None:
    """Check a composed configuration: every group against :data:`SCHEMAS`, the top level against
    :class:`RunConfig`, the numbers against :data:`CHECKS`, each variant's delta the same way, and
    ``variant`` / ``ablation`` / the entries of ``ablations`` against the names they refer to.

    Raises:
        ConfigError: one line naming the first offending key and its value.
    """
    if isinstance(cfg, (DictConfig, ListConfig)):
        try:
            tree = OmegaConf.to_container(cfg, resolve=True)
        except Exception as exc:  # an interpolation that does not resolve
            if not type(exc).__module__.startswith("omegaconf"):
                raise
            key = str(getattr(exc, "full_key", None) or "?")
            present, raw = _lookup(OmegaConf.to_container(cfg, resolve=False), key)
            raise ConfigError(f"{key}={_show(raw)}: {str(exc).strip().splitlines()[0]}" if present else f"{key}: {exc}") from None
    else:
        tree = dict(cfg)
    _check_tree(tree)
    variants = tree.get("variants") or {}
    for name, delta in variants.items():
        if not isinstance(delta, Mapping):
            raise _bad(f"variants.{name}", delta, "must be a mapping of settings (e.g. {stage2: {mass: learned}})")
        _check_tree(delta, f"variants.{name}.")
    known = ", ".join(sorted(variants)) or "none"
    base = lambda v: split_variant(v)[0]  # noqa: E731  the variant of a seeded run name
    if tree.get("variant") is not None and base(tree["variant"]) not in variants:
        raise _bad("variant", tree["variant"], f"must be one of {known} (conf/config.yaml, key variants)")
    ablations = tree.get("ablations") or {}
    for key, names in ablations.items():
        for i, v in enumerate(names or []):
            if base(v) not in variants:
                raise _bad(f"ablations.{key}[{i}]", v, f"must be one of {known} (conf/config.yaml, key variants)")
    seeds = tree.get("ablation_seeds")
    if seeds is not None and (not isinstance(seeds, (list, tuple)) or not seeds):  # each seed's range: CHECKS
        raise _bad("ablation_seeds", seeds, "must be null or a non-empty list of seeds >= 0 (e.g. [0, 1, 2, 3, 4])")
    if ablations and tree.get("ablation") not in ablations:
        raise _bad("ablation", tree.get("ablation"), f"must be one of {', '.join(sorted(ablations))} (conf/config.yaml, key ablations)")


def _schema_at(dotted: str) -> type | None:
    """The dataclass of the group at ``dotted`` (``"system.source"`` -> :class:`SourceConfig`), or ``None``."""
    head, *rest = dotted.split(".")
    cls: Any = SCHEMAS.get(head)
    for part in rest:
        if cls is None or part not in {f.name for f in dataclasses.fields(cls)}:
            return None
        tp = typing.get_type_hints(cls)[part]
        inner = [a for a in typing.get_args(tp) if dataclasses.is_dataclass(a)] if typing.get_origin(tp) in (Union, types.UnionType) else [tp]
        cls = inner[0] if inner and dataclasses.is_dataclass(inner[0]) else None
    return cls


def explain_compose_error(exc: BaseException, overrides: Sequence[str], conf_dir: str | Path | None = None) -> str:
    """One line for a Hydra composition error, naming the override (key and value) when it can.

    Args:
        exc: the exception Hydra raised while composing.
        overrides: the command line's ``key=value`` overrides.
        conf_dir: the ``conf/`` folder (lists the options of a group that has no such file).

    Returns:
        e.g. ``stage1.nope=1: unknown key (known in stage1: n_gaussians, ...)``, or the first line of the message.
    """
    text = str(exc).strip()
    first = text.splitlines()[0] if text else type(exc).__name__

    def given(key: str) -> str | None:
        for o in overrides:
            k, sep, v = o.partition("=")
            if sep and k.lstrip("+~") == key:
                return v
        return None

    m = re.search(r"Could not override '([^']+)'", first)
    if m:
        key = m.group(1)
        group, _, leaf = key.rpartition(".")
        cls = _schema_at(group) if group else None
        known = [f.name for f in dataclasses.fields(cls)] if cls else list(SCHEMAS) + [f.name for f in dataclasses.fields(RunConfig)]
        if leaf in known:  # a key of the schema this configuration does not set: Hydra adds it with '+'
            return f"{key}={given(key)}: not set in this configuration; add it with +{key}={given(key)}"
        return f"{key}={given(key)}: unknown key (known in {group or 'the top level'}: {', '.join(known)})"
    m = re.search(r"Could not find '([^'/]+)/([^']+)'", first)
    if m:
        group, name = m.groups()
        options = sorted(p.stem for p in (Path(conf_dir) / group).glob("*.yaml")) if conf_dir else []
        return f"{group}={name}: no conf/{group}/{name}.yaml" + (f" (known: {', '.join(options)})" if options else "")
    return first

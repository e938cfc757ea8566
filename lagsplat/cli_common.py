"""What every command-line stage shares: composing the configuration, the artifact paths, the resolved-config record.

Used by :mod:`lagsplat.cli` (the entry point) and the stage modules
:mod:`lagsplat.stages` and :mod:`lagsplat.stages_report`.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from collections.abc import Sequence
from typing import TYPE_CHECKING

from omegaconf import DictConfig, OmegaConf

if TYPE_CHECKING:
    from lagsplat.artifacts import Artifacts

__all__ = ["find_conf_dir", "compose", "artifacts_of", "apply_variant", "save_stage_config", "plain", "data_kind", "record_stop", "clear_stop"]


def find_conf_dir() -> Path:
    """Locate the Hydra ``conf/`` folder.

    Order: ``$LAGSPLAT_CONF``, ``./conf`` in the working directory, then the
    ``conf/`` beside the package (a source checkout / editable install).

    Raises:
        FileNotFoundError: if none has a ``config.yaml``.
    """
    cands = [os.environ.get("LAGSPLAT_CONF"), Path.cwd() / "conf", Path(__file__).resolve().parents[1] / "conf"]
    for c in cands:
        if c and (Path(c) / "config.yaml").exists():
            return Path(c).resolve()
    raise FileNotFoundError("no conf/config.yaml found: run from the project root or set LAGSPLAT_CONF")


def compose(overrides: list[str]) -> DictConfig:
    """Compose the configuration (``conf/config.yaml`` + system + overrides)."""
    from hydra import compose as hcompose
    from hydra import initialize_config_dir

    from lagsplat.config_schema import register_schemas

    register_schemas()

    with initialize_config_dir(config_dir=str(find_conf_dir()), version_base=None):
        return hcompose(config_name="config", overrides=overrides)


def artifacts_of(cfg: DictConfig) -> "Artifacts":
    """The run's artifact paths (:class:`lagsplat.artifacts.Artifacts`): ``${results_dir}/<system>/``,
    the model's under ``variants/<variant>/`` when ``variant`` is set, each overridable as ``artifacts.<name>=PATH``."""
    from lagsplat.artifacts import Artifacts

    return Artifacts.for_run(cfg.results_dir, cfg.system.name, cfg.get("variant"), plain(cfg.get("artifacts") or {}))


#: ``<variant>@seed<k>``: a variant's run with training seed ``k`` (:func:`split_variant`).
SEEDED_VARIANT = re.compile(r"^(?P<name>[^@]+)@seed(?P<seed>\d+)$")


def split_variant(v: str) -> tuple[str, int | None]:
    """``"mass_decoder@seed3"`` -> ``("mass_decoder", 3)``; a name without the suffix -> ``(name, None)``."""
    m = SEEDED_VARIANT.match(str(v))
    return (m["name"], int(m["seed"])) if m else (str(v), None)


def seeded_variants(name: str, seeds: Sequence[int] | None) -> list[str]:
    """The run names of variant ``name`` over ``seeds`` (any sequence of integers, e.g. the configuration's
    ``ablation_seeds``; ``name@seed<k>`` each; ``None``: ``[name]``, the run's own seed)."""
    return [name] if seeds is None else [f"{name}@seed{int(k)}" for k in seeds]


def apply_variant(cfg: DictConfig) -> DictConfig:
    """Merge ``variants[cfg.variant]`` into ``cfg`` (no-op without a variant).

    ``variant=<name>@seed<k>`` merges ``variants[<name>]`` and sets ``seed=k``: the
    variant's Stage 2 on the same frozen chart with another training seed (its
    artifacts under ``variants/<name>@seed<k>/``), for ablations reported as the
    median over seeds (paper §4.1).

    Raises:
        KeyError: naming the unknown variant and the known ones.
    """
    v = cfg.get("variant")
    if not v:
        return cfg
    name, seed = split_variant(v)
    known = cfg.get("variants") or {}
    if name not in known:
        raise KeyError(f"unknown variant {name!r}; known: {sorted(known)} (conf/config.yaml, key variants)")
    out = OmegaConf.merge(cfg, known[name])
    if seed is not None:
        out.seed = seed
    return out


def save_stage_config(cfg: DictConfig, stage: str, a: "Artifacts | None" = None) -> None:
    """Write the resolved configuration of ``stage`` beside its output (:meth:`lagsplat.artifacts.Artifacts.config`
    of ``a``, default the run's :func:`artifacts_of`), atomically."""
    from lagsplat.io.atomic import atomic_write

    with atomic_write((a or artifacts_of(cfg)).config(stage)) as tmp:
        tmp.write_text(OmegaConf.to_yaml(cfg, resolve=True))


def plain(node) -> dict:
    """A configuration node as a plain, resolved ``dict`` (a mapping that is already plain is copied)."""
    return OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)


def data_kind(system: DictConfig) -> str:
    """What a system's clip is: ``system.data`` when set (``real`` | ``surrogate``), else ``synthetic`` for a
    procedural source (``source.synth``) and ``real`` for a recording."""
    if system.get("data"):
        return str(system.data)
    sources = list(system.get("sources") or []) or [system.get("source") or {}]
    return "synthetic" if all(src.get("synth") for src in sources) else "real"


def record_stop(cfg: DictConfig, stage: str, reason: str) -> Path | None:
    """Record that pipeline ``stage`` stopped with the one-line ``reason``: ``stopped.json`` ``{stage, reason, time}``
    written atomically beside the stage's output (:meth:`lagsplat.artifacts.Artifacts.stopped`), so that the
    diagnosis can report the run (verdict ``cannot_diagnose``) instead of failing on a missing artifact.

    Returns:
        The record's path, or ``None`` for a stage outside :data:`lagsplat.artifacts.STOP_STAGES` or when it
        cannot be written (the stage's own error is what the user needs; this never raises ``OSError``).
    """
    import time

    from lagsplat.artifacts import STOP_STAGES
    from lagsplat.io.atomic import write_json

    if stage not in STOP_STAGES:
        return None
    try:
        path = artifacts_of(cfg).stopped(stage)
        return write_json(path, {"stage": stage, "reason": str(reason), "time": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
    except (OSError, KeyError, ValueError):
        return None


def clear_stop(cfg: DictConfig, stage: str) -> bool:
    """Remove the stop record beside ``stage``'s output when it is ``stage``'s or a later stage's (a stage that
    succeeds undoes its own stop and any stop downstream of it). Returns whether a record was removed."""
    from lagsplat.artifacts import STOP_STAGES

    if stage not in STOP_STAGES:
        return False
    try:
        path = artifacts_of(cfg).stopped(stage)
        rec = json.loads(path.read_text())
    except (OSError, ValueError, KeyError):
        return False
    recorded = rec.get("stage") if isinstance(rec, dict) else None
    if recorded in STOP_STAGES and recorded not in STOP_STAGES[STOP_STAGES.index(stage) :]:
        return False  # an earlier stage's stop: still stands
    path.unlink(missing_ok=True)
    return True

"""Typed configuration (lagsplat.config_schema): every system and experiment delta validates, a bad value
stops at start-up with one line naming key and value, the dataclasses are the one source of defaults
(the YAML repeats none with another value), and every number has a range."""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path

import pytest
import yaml
from omegaconf import OmegaConf

from lagsplat.cli import STAGES, compose, main
from lagsplat.config_check import CHECKS, ConfigError, validate_config
from lagsplat.config_schema import NESTED, SCHEMAS, RunConfig, register_schemas

ROOT = Path(__file__).resolve().parents[1]
SYSTEMS = sorted(p.stem for p in (ROOT / "conf" / "system").glob("*.yaml"))
EXPERIMENTS = sorted(p.stem for p in (ROOT / "conf" / "experiment").glob("*.yaml"))


@pytest.mark.parametrize("system", SYSTEMS)
def test_every_system_composes_and_validates(system: str) -> None:
    validate_config(compose([f"system={system}"]))


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_delta_composes_validates_and_says_what_it_is(experiment: str) -> None:
    text = (ROOT / "conf" / "experiment" / f"{experiment}.yaml").read_text()
    assert "Experiment delta" in text.split("\n\n")[0] and "Use:" in text, "the delta is documented in a comment at its top"
    cfg = compose(["system=toy", f"+experiment={experiment}"])
    validate_config(cfg)
    delta = yaml.safe_load(text)
    for group, values in delta.items():
        for k, v in values.items():
            assert cfg[group][k] == v


@pytest.mark.parametrize(
    "override, needle",
    [
        ("stage1.steps=-1", "stage1.steps=-1: must be a positive integer"),
        ("stage1.steps=1.5", "stage1.steps=1.5: must be an integer"),
        ("device=gpu", "device=gpu: must be one of cpu, cuda, auto"),
        ("stage2.mass=heavy", "stage2.mass=heavy: must be one of auto, scalar, constant, learned, decoder"),
        ("stage2.potential=concave", "stage2.potential=concave: must be one of convex, invex"),
        ("stage1.backend=opengl", "stage1.backend=opengl: must be one of auto, cpu, torch, dense, gsplat"),
        ("system.d=0", "system.d=0: must be a positive integer"),
        ("+system.protocol=mine", "system.protocol=mine: must be one of default, paper, krauss"),
        ("stage1.n_gaussians=many", "stage1.n_gaussians=many: must be an integer"),
        ("stage1.alpha_dead=1.5", "stage1.alpha_dead=1.5: must be in [0, 1]"),
        ("stage1.encoder_channels=[2,0,2]", "stage1.encoder_channels[1]=0: must be a positive integer"),
        ("stage1.background=[0,0]", "stage1.background=[0, 0]: must be a list of 3 values"),
        ("stage2.lr=0", "stage2.lr=0: must be a positive number"),
        ("system.split.train_fraction=0", "system.split.train_fraction=0: must be in (0, 1]"),
        ("+system.crop=[0,0,10]", "system.crop=[0, 0, 10]: must be a list of 4 values"),
        ("+system.source.fps=-30", "system.source.fps=-30: must be a positive number"),
        ("view.image_format=gif", "view.image_format=gif: must be one of png, jpeg"),
        ("view.initial=middle", "view.initial=middle: must be one of held_out, rest"),
        ("view.force_scale=strong", "view.force_scale=strong: must be auto or a number"),
        ("view.port=70000", "view.port=70000: must be a port number in [0, 65535]"),
        ("diagnose.refit.init=warm", "diagnose.refit.init=warm: must be one of fitted, scratch"),
        ("diagnose.split=some", "diagnose.split=some: must be one of train, held_out, all"),
        ("forces.moving_frac=2", "forces.moving_frac=2: must be in [0, 1]"),
        ("progress=maybe", "progress=maybe: must be true or false"),
        ("+diagnose.select.min_r2=high", "diagnose.select.min_r2=high: must be a finite number"),
        ("+diagnose.select.nope=1", "diagnose.select.nope=1: unknown key"),
        ("variants.mass_learned.stage2.mass=heavy", "variants.mass_learned.stage2.mass=heavy: must be one of"),
        ("variant=nope", "variant=nope: must be one of mass_constant"),
        ("ablations.inertia=[mass_learned,nope]", "ablations.inertia[1]=nope: must be one of"),
        ("variant=nope@seed2", "variant=nope@seed2: must be one of"),
        ("ablation_seeds=[]", "ablation_seeds=[]: must be null or a non-empty list"),
        ("ablation_seeds=[1,-2]", "ablation_seeds[1]=-2: must be an integer >= 0"),
        ("stage1.nope=1", "stage1.nope=1: unknown key (known in stage1: n_gaussians"),
        ("+stage2.nope=1", "stage2.nope=1: unknown key (known in stage2: mass"),
        ("nope=1", "nope=1: unknown key"),
        ("system.crop=[0,0,10,10]", "system.crop=[0,0,10,10]: not set in this configuration; add it with +system.crop=[0,0,10,10]"),
        ("system=nosuch", "system=nosuch: no conf/system/nosuch.yaml (known: "),
        ("stage1.steps=${nosuch}", "stage1.steps=${nosuch}: Interpolation key 'nosuch' not found"),
        # the dead knobs are gone
        ("stage1.w_kinematic=1", "stage1.w_kinematic=1: unknown key"),
        ("+stage1.j_decay=0.5", "stage1.j_decay=0.5: unknown key"),
        ("+stage1.w_rigid=1", "stage1.w_rigid=1: unknown key"),
    ],
)
def test_a_bad_value_stops_at_start_up_naming_key_and_value(override: str, needle: str, tmp_path: Path, capsys) -> None:
    assert main(["stage1", "system=toy", f"results_dir={tmp_path}", override]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lagsplat stage1: configuration error: ") and needle in err[0], err
    assert not any(tmp_path.iterdir())  # nothing ran


@pytest.mark.parametrize("stage", list(STAGES))
def test_every_stage_still_has_its_help(stage: str, capsys) -> None:
    assert main([stage, "--help"]) == 0
    assert capsys.readouterr().out.startswith(f"usage: python -m lagsplat {stage} ")


def test_every_entry_of_sources_is_checked_like_source() -> None:
    tree = OmegaConf.to_container(compose(["system=toy"]), resolve=True)
    tree["system"]["source"] = None
    tree["system"]["sources"] = [{"path": "a.mp4", "fps": 30.0}, {"path": "b.mp4", "fps": 0.0, "held_out": True}]
    with pytest.raises(ConfigError, match=r"^system.sources\[1\].fps=0.0: must be a positive number$"):
        validate_config(tree)
    tree["system"]["sources"][1] = {"path": "b.mp4", "fsp": 30.0}
    with pytest.raises(ConfigError, match=r"^system.sources\[1\].fsp=30.0: unknown key"):
        validate_config(tree)


def _group_defaults(cls: type) -> dict:
    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            v = f.default
        elif f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
            v = f.default_factory()  # type: ignore[misc]
        else:
            continue
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


def test_the_yaml_repeats_no_default_with_another_value() -> None:
    """One source of defaults: conf/config.yaml may spell a default out (metrics.json embeds the whole
    resolved stage2 group, so it does for stage2), but only with the dataclass's value."""
    base = yaml.safe_load((ROOT / "conf" / "config.yaml").read_text())
    groups = {**SCHEMAS, **NESTED}
    diffs = []
    for name, cls in groups.items():
        node = base
        for part in name.split("."):
            node = (node or {}).get(part)
        if not isinstance(node, dict):
            continue
        for k, v in _group_defaults(cls).items():
            if k in node and not dataclasses.is_dataclass(v) and node[k] != v:
                diffs.append(f"{name}.{k}: YAML {node[k]!r} vs {cls.__name__} {v!r}")
    for k, v in _group_defaults(RunConfig).items():  # variants / ablations: registries the YAML defines (RunConfig: none)
        if k in base and base[k] != v and k not in ("variants", "ablations"):
            diffs.append(f"{k}: YAML {base[k]!r} vs RunConfig {v!r}")
    assert not diffs, diffs


def test_the_stage2_group_matches_its_dataclass_key_for_key() -> None:
    """metrics.json embeds the resolved stage2 group: the YAML lists every Stage2Config field, in its order."""
    base = yaml.safe_load((ROOT / "conf" / "config.yaml").read_text())
    assert list(base["stage2"]) == [f.name for f in dataclasses.fields(SCHEMAS["stage2"])]


def _numbers(cls: type, prefix: str) -> list[str]:
    """Dotted keys of the int / float fields of ``cls`` (``key[]`` for lists of numbers), nested dataclasses walked."""
    out = []
    for name, tp in typing.get_type_hints(cls).items():
        union = typing.get_origin(tp) in (typing.Union, types.UnionType)
        args = [a for a in typing.get_args(tp) if a is not type(None)] if union else [tp]
        lists = [a for a in args if typing.get_origin(a) in (list, tuple)]
        inner = args[0] if len(args) == 1 else (lists[0] if len(lists) == 1 else None)  # e.g. Union[Literal["auto"], tuple]
        key = f"{prefix}{name}"
        if any(a in (int, float) for a in args) and inner not in (bool,):
            out.append(key)
        elif inner is not None and dataclasses.is_dataclass(inner):
            out += _numbers(inner, key + ".")
        elif inner is not None and typing.get_origin(inner) in (list, tuple):
            items = [a for a in typing.get_args(inner) if a is not Ellipsis]
            flat = [b for a in items for b in (typing.get_args(a) or [a])]
            if flat and all(a in (int, float, type(None)) for a in flat):
                out.append(key + "[]")
    return out


def test_every_number_has_a_range() -> None:
    keys = _numbers(RunConfig, "") + [k for g, cls in SCHEMAS.items() for k in _numbers(cls, g + ".")]
    missing = sorted(set(keys) - set(CHECKS))
    assert not missing, f"numbers without a range in lagsplat.config_check.CHECKS: {missing}"
    stale = sorted(k for k in CHECKS if k not in keys)
    assert not stale, f"CHECKS names keys no schema has: {stale}"


def test_every_group_is_registered_in_hydras_config_store() -> None:
    from hydra.core.config_store import ConfigStore

    register_schemas()
    stored = set(ConfigStore.instance().repo["schema"])
    assert stored == {f"{g}.yaml" for g in SCHEMAS} | {"run.yaml"}
    base = yaml.safe_load((ROOT / "conf" / "config.yaml").read_text())
    run = {f.name for f in dataclasses.fields(RunConfig)}
    unknown = [k for k in base if k != "defaults" and k not in SCHEMAS and k not in run]
    assert not unknown, f"keys of conf/config.yaml without a schema: {unknown}"

"""The package's layers (docs/architecture.md): every import of every module points down, never up.

Each module of ``lagsplat`` belongs to one layer (:data:`LAYERS`, bottom first).
A module may import from its own layer or below; an import of a higher layer,
at the top of a module or inside a function, fails the test with the module,
the line and both layers. So do imports of another module's private names.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "lagsplat"

# bottom to top; a module's layer is the one of its longest matching prefix
LAYERS: list[tuple[str, list[str]]] = [
    ("io", ["lagsplat", "lagsplat.io"]),
    ("signals", ["lagsplat.timeseries", "lagsplat.motion", "lagsplat.metrics"]),
    ("render and synthetic clips", ["lagsplat.render", "lagsplat.synth"]),
    ("ingest and models", ["lagsplat.ingest", "lagsplat.prepare", "lagsplat.views", "lagsplat.views_sharp", "lagsplat.models"]),
    ("dynamics", ["lagsplat.dynamics"]),
    ("chart", ["lagsplat.chart", "lagsplat.chart_refine", "lagsplat.chart_gate"]),
    ("train", ["lagsplat.train"]),
    ("artifacts", ["lagsplat.artifacts"]),
    ("evaluate, forces, export", ["lagsplat.evaluate", "lagsplat.force", "lagsplat.force3d", "lagsplat.force_checks", "lagsplat.export"]),
    ("diagnose, baselines, viewer, figures", ["lagsplat.diagnose", "lagsplat.baselines", "lagsplat.viewer", "lagsplat.viz"]),
    ("report", ["lagsplat.report"]),
    ("cli", ["lagsplat.cli", "lagsplat.__main__", "lagsplat.config_schema", "lagsplat.config_check", "lagsplat.cli_common", "lagsplat.stages", "lagsplat.stages_report", "lagsplat.stages_baselines", "lagsplat.stages_deformation"]),
]


def layer_of(module: str) -> int:
    """Index in :data:`LAYERS` of ``module`` (longest matching prefix).

    Raises:
        KeyError: if no layer claims it.
    """
    best, rank = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best:
                best, rank = len(p), i
    if rank is None:
        raise KeyError(module)
    return rank


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports_of(path: Path, mod: str | None = None) -> list[tuple[int, str, list[str]]]:
    """``(line, imported module, imported names)`` of every ``lagsplat`` import in ``path`` (module ``mod``,
    default its name in the package), nested ones included."""
    mod = mod or module_name(path)
    pkg = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target == "lagsplat" or target.startswith("lagsplat."):
                names = [a.name for a in node.names]
                # "from lagsplat import metrics" imports the submodule lagsplat.metrics
                subs = [f"{target}.{n}" for n in names if (PKG.parent / (target + "." + n).replace(".", "/")).with_suffix(".py").exists()
                        or (PKG.parent / (target + "." + n).replace(".", "/")).is_dir()]  # fmt: skip
                if subs:
                    out += [(node.lineno, s, []) for s in subs]
                else:
                    out.append((node.lineno, target, names))
        elif isinstance(node, ast.Import):
            out += [(node.lineno, a.name, []) for a in node.names if a.name.startswith("lagsplat")]
    return out


MODULES = sorted(PKG.rglob("*.py"))


def test_every_module_has_a_layer() -> None:
    missing = [module_name(p) for p in MODULES if not _has_layer(module_name(p))]
    assert not missing, f"modules outside every layer of tests/test_layers.py (and docs/architecture.md): {missing}"


def _has_layer(m: str) -> bool:
    try:
        layer_of(m)
    except KeyError:
        return False
    return True


@pytest.mark.parametrize("path", MODULES, ids=lambda p: module_name(p))
def test_imports_point_down(path: Path) -> None:
    src = module_name(path)
    here = layer_of(src)
    up = [
        f"{path.relative_to(PKG.parent)}:{line} imports {target} (layer '{LAYERS[layer_of(target)][0]}') from layer '{LAYERS[here][0]}'"
        for line, target, _ in imports_of(path)
        if _has_layer(target) and layer_of(target) > here
    ]
    assert not up, "imports pointing up a layer:\n" + "\n".join(up)


@pytest.mark.parametrize("path", MODULES, ids=lambda p: module_name(p))
def test_no_private_names_of_other_modules(path: Path) -> None:
    src = module_name(path)
    bad = []
    for line, target, names in imports_of(path):
        if target == src:
            continue
        bad += [f"{line}: {n} from {target}" for n in names if n.startswith("_") and not n.startswith("__")]
        # a private module (io/_x.py) is for its own package only
        priv = [p for p in target.split(".") if p.startswith("_") and not p.startswith("__")]
        if priv and not src.startswith(target.rpartition(".")[0] + "."):
            bad.append(f"{line}: private module {target}")
    assert not bad, f"{path.relative_to(PKG.parent)} imports private names of other modules: {bad}"


def test_the_checker_sees_an_upward_import(tmp_path: Path) -> None:
    """The test itself: a module of a low layer importing the CLI is caught, nested imports included."""
    fake = tmp_path / "probe.py"
    fake.write_text("import numpy\n\ndef f():\n    from lagsplat.cli import main\n    from lagsplat import chart\n    return main\n")
    found = [(t, layer_of(t)) for _, t, _ in imports_of(fake, "lagsplat.io.zz_layer_probe")]
    assert found == [("lagsplat.cli", len(LAYERS) - 1), ("lagsplat.chart", layer_of("lagsplat.chart"))]
    assert layer_of("lagsplat.io.zz_layer_probe") == 0

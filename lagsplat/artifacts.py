"""The artifact chain: where every file a run reads or writes lives, and how each is loaded.

One system's run writes, under ``${results_dir}/<system>/`` (paper §3, the
two-stage pipeline; ``docs/architecture.md``)::

    clip.npz        ingest    frames, timestamps, actuation, split          (lagsplat.io.clip)
    views/          views     cached novel views per frame and their cameras (3-D systems; lagsplat.views)
    stage1.pt       stage1    encoder + conditioned-Gaussian decoder         (lagsplat.models.autoencoder)
    chart.npz       chart     whitening, q, G_bar, AE floor                  (lagsplat.chart)
    stage2.pt       stage2    latent Lagrangian                              (lagsplat.train.stage2)
    metrics.json    evaluate  the protocol's metrics                         (lagsplat.evaluate)
    figures/rollout.png, figures/forces.png, forces.json, diagnosis/...
    figures/deformation.png   deformation   the two decoders' velocity fields (paper App. B)
    variants/deformation/stage1.pt           deformation   the deformation decoder's Stage 1 (paper App. B)
    export/         export    the model for use outside lagsplat: dynamics.py, weights, TorchScript, CSV, .ply (lagsplat.export)
    variants/<name>/          a variant: stage2 onwards on the same chart, or (decoder_variant) its own stage1 and chart
    config/<stage>.yaml       the resolved configuration of each stage

``stage2.pt`` and everything after it belong to the *model directory*: the
system folder, or ``variants/<name>/`` under it for an ablation on the same
frozen chart. Every path can be overridden one by one (the configuration's
``artifacts`` group; Snakemake passes its ``{input}`` and ``{output}`` that
way), so a stage reads exactly the files its rule declares. Outside the system
folder: ``source`` (the source clip download writes and ingest reads; standard:
``system.source.path``), and for the table stages ``table_inputs`` (the files
read, in row order) and ``table_tex``, ``table_csv``, ``table_md``, ``table_json``
(the files written; standard: ``${results_dir}/tables/<name>.<suffix>``,
:func:`table_path`).

This module is the only place that spells an artifact's file name.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

if TYPE_CHECKING:  # the loaders import torch; the paths alone (the Snakefile's DAG) need none of it
    from lagsplat.chart import Chart
    from lagsplat.io.clip import Clip
    from lagsplat.models.autoencoder import AutoEncoder
    from lagsplat.views import ViewSet

__all__ = [
    "Artifacts",
    "STOPPED_FILE",
    "STOP_STAGES",
    "table_path",
    "seed_metrics_path",
    "variant_metrics_path",
    "DIAGNOSIS_FILES",
    "DIAGNOSIS_FIGURES",
    "DEFORMATION_VARIANT",
    "LIST_ARTIFACTS",
]

DIAGNOSIS_FILES = {"report_md": "report.md", "report_json": "report.json", "config": "config.yaml", "refit": "refit.pt"}
"""What the diagnosis writes into its folder (``diagnosis/``): the report, its record, the resolved
configuration and the refitted Stage-2 model (:mod:`lagsplat.diagnose.report`)."""

DEFORMATION_VARIANT = "deformation"
"""Folder of the deformation decoder's run under ``variants/`` (paper App. B, :mod:`lagsplat.stages_deformation`)."""

LIST_ARTIFACTS = ("table_inputs",)
"""The artifacts given as a list of paths (``'artifacts.table_inputs=[a,b]'``); every other one is one path."""

STOPPED_FILE = "stopped.json"
"""The record a pipeline stage leaves when it stops with a one-line reason (``{stage, reason, time}``;
written by the command line, :func:`lagsplat.cli_common.record_stop`), in the folder of what the stage
writes; removed when that stage, or one before it, later succeeds."""

STOP_STAGES = ("ingest", "views", "stage1", "chart", "stage2", "evaluate")
"""The pipeline stages whose stop is recorded, in pipeline order."""

DIAGNOSIS_FIGURES = {
    "where_time": "where_time.png",
    "where_state": "where_state.png",
    "where_latent": "where_latent.png",
    "where_image": "where_image.png",
    "gap": "gap.png",
    "backbone": "backbone.png",
}
"""The diagnosis figures, inside ``diagnosis/figures/``: where the gap shows (:mod:`lagsplat.diagnose.where`),
the held-out gap before / after the refit, and the backbone curves (frequency and damping ratio against
amplitude, :mod:`lagsplat.diagnose.backbone`)."""


@dataclass(frozen=True)
class Artifacts:
    """The artifact paths of one system's run (module docstring).

    Attributes:
        clip, views, stage1, chart: the frozen upstream artifacts (system folder; ``views`` a folder, 3-D systems only).
        prepare_preview: what the automatic preparation chose, drawn at ingest (``prepare.png``; system folder).
        stage2, metrics, rollout_figure, forces, forces_figure: the model's artifacts (model folder).
        extrapolation, extrapolation_figure: the extrapolation protocol's record and figure (paper §4.3, Fig. 5; model folder).
        diagnosis: the diagnosis folder (``report.md``, ``report.json``, ``figures/``, ``refit.pt``).
        deformation_figure: the decoder comparison's figure (paper App. B, Fig. deform-velocity; system folder).
        novel_views_video, novel_views_figure: a 3-D model's novel views, orbit video and contact sheet (model folder).
        robot_rollout_figure, robot_forces_figure, robot_forces: the soft robot's figures and the force
            figure's record (paper §4.4-4.5; model folder).
        export: the export folder (``dynamics.py``, ``weights.npz``, TorchScript terms, ``model.json``, CSV
            tables, ``.ply`` splats; :mod:`lagsplat.export`; model folder).
        deformation_stage1: the deformation decoder's Stage 1, trained by the decoder comparison (paper App. B;
            ``variants/deformation/stage1.pt``; the rest of that run: :meth:`decoder_variant`).
        source: the source clip (download writes it, ingest reads it); ``None``: ``system.source.path``.
        table_inputs: the files a table stage reads, in the order of its rows; ``None``: its runs' standard paths.
        table_tex, table_csv, table_md, table_json: the files a table stage writes; ``None``:
            ``${results_dir}/tables/<name>.<suffix>`` (:meth:`table`).
        system_dir, model_dir: the two folders.
    """

    system_dir: Path
    model_dir: Path
    clip: Path
    prepare_preview: Path
    views: Path
    stage1: Path
    chart: Path
    stage2: Path
    metrics: Path
    rollout_figure: Path
    forces: Path
    forces_figure: Path
    diagnosis: Path
    extrapolation: Path
    extrapolation_figure: Path
    deformation_figure: Path
    novel_views_video: Path
    novel_views_figure: Path
    robot_rollout_figure: Path
    robot_forces_figure: Path
    robot_forces: Path
    export: Path
    deformation_stage1: Path
    source: Path | None = None
    table_inputs: tuple[Path, ...] | None = None
    table_tex: Path | None = None
    table_csv: Path | None = None
    table_md: Path | None = None
    table_json: Path | None = None

    @classmethod
    def at(cls, system_dir: str | Path, model_dir: str | Path | None = None) -> "Artifacts":
        """The standard layout under ``system_dir`` (model artifacts in ``model_dir``, default the same folder)."""
        s = Path(system_dir)
        m = Path(model_dir) if model_dir is not None else s
        return cls(
            system_dir=s,
            model_dir=m,
            clip=s / "clip.npz",
            prepare_preview=s / "prepare.png",
            views=s / "views",
            stage1=s / "stage1.pt",
            chart=s / "chart.npz",
            stage2=m / "stage2.pt",
            metrics=m / "metrics.json",
            rollout_figure=m / "figures" / "rollout.png",
            forces=m / "forces.json",
            forces_figure=m / "figures" / "forces.png",
            diagnosis=m / "diagnosis",
            extrapolation=m / "extrapolation.json",
            extrapolation_figure=m / "figures" / "extrapolation.png",
            deformation_figure=s / "figures" / "deformation.png",
            novel_views_video=m / "figures" / "novel_views.mp4",
            novel_views_figure=m / "figures" / "novel_views.png",
            robot_rollout_figure=m / "figures" / "robot_rollout.png",
            robot_forces_figure=m / "figures" / "robot_forces.png",
            robot_forces=m / "robot_forces.json",
            export=m / "export",
            deformation_stage1=s / "variants" / DEFORMATION_VARIANT / "stage1.pt",
        )

    @classmethod
    def for_run(cls, results_dir: str | Path, system: str, variant: str | None = None, overrides: Mapping[str, Any] | None = None) -> "Artifacts":
        """The paths of system ``system`` under ``results_dir``; a ``variant`` moves the model artifacts to ``variants/<variant>/``.

        Args:
            overrides: artifact name -> path (the configuration's ``artifacts`` group; a list of paths for
                :data:`LIST_ARTIFACTS`); ``None`` values keep the standard path.

        Raises:
            KeyError: naming an override that is not an artifact, and the known ones.
        """
        s = Path(results_dir) / system
        a = cls.at(s, s / "variants" / str(variant) if variant else s)
        given = {k: v for k, v in (overrides or {}).items() if v is not None}
        known = cls.names()
        bad = sorted(set(given) - set(known))
        if bad:
            raise KeyError(f"unknown artifacts {bad}; known: {known} (configuration group artifacts)")
        return replace(a, **{k: tuple(Path(p) for p in v) if k in LIST_ARTIFACTS else Path(v) for k, v in given.items()})

    def decoder_variant(self, name: str) -> "Artifacts":
        """The same run with its own Stage 1 (another decoder, paper App. B): every artifact, configurations
        included, under ``variants/<name>/`` except the clip, which is this run's."""
        return replace(Artifacts.at(self.system_dir / "variants" / str(name)), clip=self.clip)

    def table(self, results_dir: str | Path, name: str, suffix: str = ".tex") -> Path:
        """The ``suffix`` file (``.tex``, ``.csv``, ``.md`` or ``.json``) a table stage writes: ``table_<suffix>``
        when given, else ``${results_dir}/tables/<name><suffix>`` (:func:`table_path`)."""
        given = getattr(self, "table_" + suffix.lstrip("."))
        return Path(given) if given is not None else table_path(results_dir, name, suffix)

    def table_sources(self, standard: list) -> list:
        """What a table stage reads: ``standard`` (paths, ``None`` for a row it leaves out, or nested lists of
        them), its paths replaced in order by :attr:`table_inputs` when given.

        Raises:
            ValueError: when ``table_inputs`` does not hold one path per standard path.
        """
        if self.table_inputs is None:
            return standard
        want = _count_paths(standard)
        if want != len(self.table_inputs):
            raise ValueError(f"artifacts.table_inputs: {len(self.table_inputs)} paths for the {want} files this table reads")
        given = iter(self.table_inputs)

        def fill(node):
            if node is None:
                return None
            return [fill(n) for n in node] if isinstance(node, (list, tuple)) else next(given)

        return fill(standard)

    @classmethod
    def names(cls) -> list[str]:
        """The names of the overridable artifacts (``artifacts.<name>=PATH``)."""
        return [f.name for f in fields(cls) if not f.name.endswith("_dir")]

    def config(self, stage: str) -> Path:
        """The resolved configuration saved by ``stage``: ``config/<stage>.yaml`` beside its output."""
        up = stage in ("ingest", "views", "stage1", "chart")
        return (self.system_dir if up else self.model_dir) / "config" / f"{stage}.yaml"

    def stopped(self, stage: str) -> Path:
        """Where ``stage``'s stop record lives (:data:`STOPPED_FILE`): beside its output, in the system folder
        for the stages up to the chart, in the model folder from Stage 2 on."""
        up = stage in ("download", "ingest", "views", "stage1", "chart")
        return (self.system_dir if up else self.model_dir) / STOPPED_FILE

    def load_stopped(self, upto: str = "stage2") -> dict | None:
        """The stop record of a stage up to ``upto`` (:data:`STOP_STAGES`) that left this run without its
        artifacts, or ``None``: ``{"stage", "reason", "time", "path"}``, the system folder's first.

        A record that cannot be read (not JSON, no ``stage``) is ignored.
        """
        last = STOP_STAGES.index(upto)
        for path in dict.fromkeys((self.system_dir / STOPPED_FILE, self.model_dir / STOPPED_FILE)):
            try:
                rec = json.loads(path.read_text())
            except (OSError, ValueError):
                continue
            if isinstance(rec, dict) and rec.get("stage") in STOP_STAGES[: last + 1]:
                return {**rec, "path": str(path)}
        return None

    @property
    def report_md(self) -> Path:
        """The diagnosis report, ``diagnosis/report.md``."""
        return self.diagnosis / DIAGNOSIS_FILES["report_md"]

    @property
    def report_json(self) -> Path:
        """The diagnosis record, ``diagnosis/report.json``."""
        return self.diagnosis / DIAGNOSIS_FILES["report_json"]

    @property
    def diagnosis_config(self) -> Path:
        """The diagnosis stage's resolved configuration, ``diagnosis/config.yaml``."""
        return self.diagnosis / DIAGNOSIS_FILES["config"]

    @property
    def diagnosis_figures(self) -> Path:
        """The diagnosis figures, ``diagnosis/figures/``."""
        return self.diagnosis / "figures"

    # ----------------------------------------------------------------- loading
    def load_clip(self) -> Clip:
        """``clip.npz`` (:func:`lagsplat.io.clip.load_clip`; raises ``ClipError``/``FileNotFoundError`` naming the file)."""
        from lagsplat.io.clip import load_clip

        return load_clip(self.clip)

    def load_views(self) -> ViewSet:
        """``views/`` (:func:`lagsplat.views.load_views`; raises ``FileNotFoundError`` naming the folder if never computed)."""
        from lagsplat.views import load_views

        return load_views(self.views)

    def load_stage1(self) -> AutoEncoder:
        """``stage1.pt`` (:func:`lagsplat.models.autoencoder.load_stage1`)."""
        from lagsplat.models.autoencoder import load_stage1

        return load_stage1(self.stage1)

    def load_stage1_history(self) -> dict:
        """The training history saved in ``stage1.pt`` (attempts, losses, the gated chart; an empty dict for a
        checkpoint without one).

        Raises:
            FileNotFoundError: naming the file if it is missing.
        """
        import torch

        if not self.stage1.exists():
            raise FileNotFoundError(f"{self.stage1}: stage-1 checkpoint not found")
        ck = torch.load(self.stage1, map_location="cpu", weights_only=False)
        return ck.get("history") or {}

    def load_chart(self) -> Chart:
        """``chart.npz`` (:func:`lagsplat.chart.load_chart`)."""
        from lagsplat.chart import load_chart

        return load_chart(self.chart)

    def load_stage2(self) -> tuple[Any, dict]:
        """``stage2.pt``: ``(Lagrangian in eval mode, checkpoint dict)`` (:func:`lagsplat.train.stage2.load_stage2`)."""
        from lagsplat.train.stage2 import load_stage2

        return load_stage2(self.stage2)

    def load_metrics(self) -> dict | None:
        """``metrics.json`` as a dict, or ``None`` when the model was not evaluated.

        Raises:
            ValueError: naming the file if it is not valid JSON.
        """
        if not self.metrics.exists():
            return None
        try:
            return json.loads(self.metrics.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{self.metrics}: not valid JSON ({exc})") from exc

    def require(self, *names: str) -> None:
        """Fail early when an upstream artifact is missing.

        Raises:
            FileNotFoundError: naming the first missing file and the stage that writes it.
        """
        writer = {"clip": "ingest", "stage1": "stage1", "chart": "chart", "stage2": "stage2", "metrics": "evaluate"}
        for n in names:
            p = getattr(self, n)
            if not Path(p).exists():
                raise FileNotFoundError(f"{p}: not found; run the {writer.get(n, n)} stage first (python -m lagsplat {writer.get(n, n)} system=...)")


def _count_paths(node) -> int:
    """The paths in ``node``: a path, ``None`` or a nested list of them."""
    if node is None:
        return 0
    return sum(_count_paths(n) for n in node) if isinstance(node, (list, tuple)) else 1


def table_path(results_dir: str | Path, name: str, suffix: str = ".tex") -> Path:
    """A table of results: ``${results_dir}/tables/<name><suffix>`` (``.tex``, ``.csv``, ``.md`` or ``.json``)."""
    return Path(results_dir) / "tables" / f"{name}{suffix}"


def seed_metrics_path(results_dir: str | Path, seeds_dir: str, seed: int, system: str) -> Path:
    """``metrics.json`` of ``system`` trained with ``seed``: ``${results_dir}/<seeds_dir>/seed<k>/<system>/metrics.json``."""
    return Artifacts.for_run(Path(results_dir) / str(seeds_dir) / f"seed{int(seed)}", system).metrics


def variant_metrics_path(results_dir: str | Path, system: str, variant: str | None) -> Path:
    """``metrics.json`` of ``system`` (of its ``variant`` when given)."""
    return Artifacts.for_run(results_dir, system, variant).metrics

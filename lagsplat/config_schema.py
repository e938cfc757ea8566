"""Typed configuration: one dataclass per group of ``conf/``, checked at start-up.

Every group of ``conf/config.yaml`` and the ``system`` group of
``conf/system/<name>.yaml`` has a dataclass: the stages' own settings classes
(:class:`~lagsplat.train.stage1.Stage1Config`, :class:`~lagsplat.train.stage2.Stage2Config`,
:class:`~lagsplat.evaluate.paper.EvalConfig`, :class:`~lagsplat.evaluate.krauss.KraussEvalConfig`,
:class:`~lagsplat.forces.checks.ForceCheckConfig`, :class:`~lagsplat.diagnose.report.DiagnoseConfig`
with :class:`~lagsplat.diagnose.where.WhereConfig` and :class:`~lagsplat.diagnose.refit.RefitConfig`)
and the ones below for the groups without one. They are registered in Hydra's
ConfigStore (group ``schema``: ``schema/<group>``, ``schema/run``) and are the
one source of defaults: ``conf/config.yaml`` spells them out for reading, and
``tests/test_config_schema.py`` fails if it gives one another value.

:func:`lagsplat.config_check.validate_config` reads a composed configuration
against them before any work (choices are the ``Literal`` annotations here).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Optional, Union

from hydra.core.config_store import ConfigStore

from lagsplat.artifacts import LIST_ARTIFACTS, Artifacts
from lagsplat.baselines.deformation_compare import DeformationCompareConfig
from lagsplat.baselines.extrapolation import ExtrapolationConfig
from lagsplat.baselines.gp2d_field import GP2DConfig
from lagsplat.diagnose.settings import DiagnoseConfig, RefitConfig, WhereConfig
from lagsplat.evaluate.settings import EvalConfig, KraussEvalConfig
from lagsplat.forces.checks import ForceCheckConfig
from lagsplat.train.stage1 import Stage1Config
from lagsplat.train.stage2 import Stage2Config

__all__ = [
    "register_schemas", "structured_node", "SCHEMAS", "NESTED", "RunConfig", "SystemConfig", "SourceConfig", "SplitConfig", "ChartConfig",
    "ViewConfig", "ViewsConfig", "ScaleConfig", "RenderConfig", "DownloadConfig", "TableConfig", "SeedTableConfig", "KraussTableConfig", "ArtifactsConfig",
]  # fmt: skip


# ----------------------------------------------------------------------------- the groups without a settings class
@dataclass
class SourceConfig:
    """Where a system's clip comes from: ``system.source``, or one entry of ``system.sources`` (:mod:`lagsplat.ingest`).

    Attributes:
        file: file name under ``raw_dir`` (the download rule's target).
        path: video file, image folder, ``.npz`` or ``.mcap`` (relative to the working directory).
        url, sha256: where the download stage fetches the file, and its SHA256 (hex).
        member, archive_file: a file inside a zip archive and where a downloaded archive is kept
            (:mod:`lagsplat.io.zenodo`).
        fps: true capture rate, Hz (> 0); required for image folders.
        dt: frame interval, s (> 0; ``.npz`` only, alternative to ``fps``).
        image_topic: ``.mcap`` image topic.
        actuation: ``.npz`` keys or ``.mcap`` topics of the actuation (one name or a list).
        max_fps, jitter_tol: timing rule (:mod:`lagsplat.io.timing`): highest plausible rate (Hz), jitter tolerance.
        synth: a procedural clip of :mod:`lagsplat.synth` (generator name) instead of ``path``.
        params: the generator's keyword arguments.
        generator: how a rule makes a simulated source file (the soft robot, :mod:`lagsplat.synth.continuum_robot`;
            the 3-D pendulum, :mod:`lagsplat.synth.pendulum3d`).
        held_out: ``system.sources`` entries: this recording is kept out of training.
        frames: ``system.sources`` entries: ``[start, stop)`` of this recording's frames.
    """

    file: Optional[str] = None
    path: Optional[str] = None
    url: Optional[str] = None
    sha256: Optional[str] = None
    member: Optional[str] = None
    archive_file: Optional[str] = None
    fps: Optional[float] = None
    dt: Optional[float] = None
    image_topic: Optional[str] = None
    actuation: Optional[Union[str, list[str]]] = None
    max_fps: Optional[float] = None
    jitter_tol: Optional[float] = None
    synth: Optional[str] = None
    params: Optional[dict] = None
    generator: Optional[dict] = None
    held_out: bool = False
    frames: Optional[tuple[Optional[int], Optional[int]]] = None


@dataclass
class SplitConfig:
    """The contiguous train / held-out split (``system.split``): ``n_train = int(train_fraction * T)``, fraction in (0, 1],
    or ``auto`` (video sources; :func:`lagsplat.prepare.auto_split`: three periods of the motion held out;
    the command line's default for a video whose configuration gives no split)."""

    train_fraction: Union[Literal["auto"], float] = 0.8


@dataclass
class ScaleConfig:
    """What a length in the image is in metres (``system.scale``; :mod:`lagsplat.diagnose.units`).

    Attributes:
        points: two points ``[x0, y0, x1, y1]`` in the source video's pixels (a ruler's marks, a known part).
        metres: their distance, m (> 0).
        pendulum_length_m: a pendulum's length (pivot to the bob's centre), m: the report then gives the
            amplitude in degrees and compares the length the frequency implies.
    """

    points: Optional[tuple[float, float, float, float]] = None
    metres: Optional[float] = None
    pendulum_length_m: Optional[float] = None


@dataclass
class ViewsConfig:
    """A 3-D system's cached novel views (``system.views``; :mod:`lagsplat.views`).

    Attributes:
        source: ``synthetic`` | ``cameras`` | ``sharp`` (:data:`lagsplat.views.VIEW_SOURCES`).
        path, cameras: ``synthetic``: the views NPZ (``images [T,M,H,W,3]``, ``t``) and the JSON of its ``M + 1`` cameras.
        videos, calibration, fps: ``cameras``: one video per extra camera, the JSON of ``M + 1`` cameras (main first), their rate.
        command, checkpoint: ``sharp``: the command (default ``sharp``) and the weights file.
        n_views, angle_deg: ``sharp``: view cameras on a cone of this half-angle around the main camera (:mod:`lagsplat.views_sharp`).
        holdout: views never used for training, scored as novel views (indices into the ``M`` views).
    """

    source: Literal["synthetic", "cameras", "sharp"] = "synthetic"
    path: Optional[str] = None
    cameras: Optional[str] = None
    videos: Optional[list[str]] = None
    calibration: Optional[str] = None
    fps: Optional[float] = None
    command: Optional[str] = None
    checkpoint: Optional[str] = None
    n_views: int = 8
    angle_deg: float = 10.0
    holdout: list[int] = field(default_factory=list)


@dataclass
class SystemConfig:
    """One system (``conf/system/<name>.yaml``, group ``system``; read by :mod:`lagsplat.ingest` and the stages).

    Attributes:
        name: results go to ``${results_dir}/<name>/``.
        title, provenance: shown in figures, tables and ``metrics.json``.
        d: latent dimension = degrees of freedom of the chart (>= 1).
        protocol: evaluation protocol (:data:`lagsplat.evaluate.PROTOCOLS`; ``default`` = ``paper``).
        data: what the clip is (tables label rows by it); ``None``: ``synthetic`` for a ``synth``
            source, else ``real`` (:func:`lagsplat.cli_common.data_kind`).
        truth: the simulator's truth beside the source: the soft robot's sidecar JSON (its natural frequencies), or an
            NPZ with the true coordinate ``q`` per source frame (the paper protocol's ``eps_freq_truth``).
        segments: soft robot: number of segments.
        source, sources: one recording, or several (multi-clip training; see :mod:`lagsplat.ingest`).
        frames: ``[start, stop)`` of source frames (``stop`` may be null).
        crop: ``[x0, y0, x1, y1]``, native pixels; ``auto`` (video sources): the region of interest
            read off the motion (:mod:`lagsplat.prepare`); ``None``: the whole frame.
        resize: ``[width, height]`` of the clip, pixels; ``auto`` (video sources): the working
            resolution at which the moving object spans enough pixels; ``None``: native size.
        split: :class:`SplitConfig`.
        stabilise: ``auto`` or ``True`` (video sources with an automatic crop or size): a hand-held camera's
            sway is read and taken out where it stills the picture (:mod:`lagsplat.prepare.stabilise`); ``False``:
            the frames are read as they are (a camera on a tripod).
        views: :class:`ViewsConfig` of a 3-D system (``stage1.decoder: conditioned3d``), ``None`` for a 2-D one.
        scale: :class:`ScaleConfig`, a known length in the image (the report's physical units), or ``None``.
    """

    name: str = "?"
    title: Optional[str] = None
    d: int = 1
    provenance: str = ""
    protocol: Literal["default", "paper", "krauss"] = "default"
    data: Optional[Literal["real", "surrogate", "synthetic"]] = None
    truth: Optional[str] = None
    segments: Optional[int] = None
    source: Optional[SourceConfig] = None
    sources: Optional[list[SourceConfig]] = None
    frames: Optional[tuple[Optional[int], Optional[int]]] = None
    crop: Optional[Union[Literal["auto"], tuple[int, int, int, int]]] = "auto"
    resize: Optional[Union[Literal["auto"], tuple[int, int]]] = "auto"
    split: SplitConfig = field(default_factory=SplitConfig)
    stabilise: Union[Literal["auto"], bool] = "auto"
    views: Optional[ViewsConfig] = None
    scale: Optional[ScaleConfig] = None


@dataclass
class ChartConfig:
    """The chart (``chart`` group; paper §3.2 "Reading the chart", :func:`lagsplat.chart.build_chart`).

    Attributes:
        n_metric_samples: training frames the metric ``G_bar`` averages over (>= 1).
        rho: whitening regulariser (> 0).
        refine_iters: Levenberg-Marquardt steps per frame of :func:`lagsplat.chart.refine.refine_latents`;
            the refined chart is used where it passes the gate with less noise than the encoder's
            (:func:`lagsplat.chart.gate.gated_chart`); 0: the paper's chart, the encoder's output
            (``conf/experiment/encoder_chart.yaml``).
        gate: Stage 2 refuses a chart that fails the quality gate (:func:`lagsplat.chart.gate.chart_gate`);
            ``false`` runs it anyway and marks the metrics as read on a failed chart.
    """

    n_metric_samples: int = 64
    rho: float = 0.01
    refine_iters: int = 8
    gate: bool = True


@dataclass
class ViewConfig:
    """The interactive viewer (``view`` group; :func:`lagsplat.stages_report.stage_view`, :mod:`lagsplat.viewer`).

    Attributes:
        port: on 127.0.0.1; 0 = any free port.
        sigma: brush radius at the press, pixels of the training resolution (> 0).
        force_scale: drag spring, pixel force per pixel of stretch (> 0), or ``"auto"``.
        kappa: energy factor of forces (> 0; :func:`lagsplat.forces.transport.calibrate_kappa`).
        initial: start state: first held-out encoded frame with its velocity, or rest.
        render_scale: render at this multiple of the training resolution (> 0).
        image_format: frames over the websocket.
        max_substeps: integrator sub-steps per frame interval, at most (>= 1).
        open_browser: open the page in the default browser.
        max_seconds: stop after this many seconds (> 0); ``None``: until Ctrl-C.
        force_3d: a 3-D model (viser viewer): the push, world units (> 0), or ``"auto"``
            (:class:`lagsplat.viewer.viewer3d.Session3D`).
        render_3d: a 3-D model: ``browser`` (viser draws splats) or ``server`` (the decoder's rasteriser renders each
            browser's camera at ``render_scale`` times the training height; :func:`lagsplat.viewer.viewer3d.serve_viser`).
    """

    port: int = 8765
    sigma: float = 2.0
    force_scale: Union[Literal["auto"], float] = "auto"
    kappa: float = 1.0
    initial: Literal["held_out", "rest"] = "held_out"
    render_scale: float = 1.0
    image_format: Literal["png", "jpeg"] = "png"
    max_substeps: int = 8
    open_browser: bool = False
    max_seconds: Optional[float] = None
    force_3d: Union[Literal["auto"], float] = "auto"
    render_3d: Literal["browser", "server"] = "browser"


@dataclass
class RenderConfig:
    """Novel views of a 3-D model (``render`` group; :func:`lagsplat.stages_report.stage_render`, :mod:`lagsplat.viz.novel_views`).

    Attributes:
        camera: ``orbit`` (an orbit through the main camera around where the cameras look) or a JSON file of cameras.
        n_cameras: cameras on the orbit (>= 1).
        size: ``[width, height]`` of the renders, px; ``None``: twice the training resolution.
        frame: the clip frame whose encoded state is shown (and the rollout starts from); ``None``: the first held-out frame.
        rollout_s: seconds of free Stage-2 rollout from that state, one frame per camera step (0: the state alone).
        fps: frame rate of the video.
    """

    camera: str = "orbit"
    n_cameras: int = 36
    size: Optional[tuple[int, int]] = None
    frame: Optional[int] = None
    rollout_s: float = 0.0
    fps: float = 15.0


@dataclass
class DownloadConfig:
    """The download stage (``download`` group): only the source whose ``file`` is ``file`` (``None``: all);
    ``archive``: a local copy of the zip a ``source.member`` comes from."""

    file: Optional[str] = None
    archive: Optional[str] = None


@dataclass
class TableConfig:
    """``python -m lagsplat table`` (``table`` group): ``results/tables/<name>.tex/.csv`` from the systems' ``metrics.json``."""

    name: str = "physical"
    systems: list[str] = field(default_factory=lambda: ["toy", "oscillating_cart", "red_apple_pendulum"])


@dataclass
class SeedTableConfig:
    """``python -m lagsplat seed_table`` (``seed_table`` group): the seeds (>= 0) and the folder under ``results_dir``."""

    seeds: list[int] = field(default_factory=lambda: [0, 1, 2, 3, 4])
    dir: str = "seeds"


@dataclass
class KraussTableConfig:
    """``python -m lagsplat krauss_table`` (``krauss_table`` group; paper Table 4): the systems of the
    one- and two-segment rows and the two-segment variants of the ablation rows."""

    name: str = "krauss"
    one_segment: Optional[str] = "krauss_1seg"
    two_segments: Optional[str] = "krauss_2seg"
    ablation: list[str] = field(default_factory=lambda: ["mass_decoder", "mass_constant"])


@dataclass
class RobotFigureConfig:
    """``python -m lagsplat robot_figures`` (``robot_figures`` group; :mod:`lagsplat.viz.robot`).

    Attributes:
        rollout_s: seconds of free rollout from the first held-out frame (paper: 30 s).
        size: decoded frames rendered at ``size x size`` px (paper: 256).
        sigma: latent smoothing of the rollout's initial state, frames.
        brush_sigma: radius of the force brush, px of the recording.
        displacement: the common force magnitude moves the most responsive application point by this share of
            the body's length.
    """

    rollout_s: float = 30.0
    size: int = 256
    sigma: float = 1.0
    brush_sigma: float = 1.5
    displacement: float = 0.15


ArtifactsConfig = dataclasses.make_dataclass(
    "ArtifactsConfig",
    [(n, Optional[list[str]] if n in LIST_ARTIFACTS else Optional[str], None) for n in Artifacts.names()],
    namespace={"__doc__": "Per-artifact path overrides (``artifacts`` group; :class:`lagsplat.artifacts.Artifacts`); None = the standard path."},
)


@dataclass
class RunConfig:
    """The top level of ``conf/config.yaml`` (keys outside the groups).

    Attributes:
        results_dir: artifacts go to ``${results_dir}/${system.name}/``.
        raw_dir: where downloaded source clips are kept.
        seed: RNG seed of the training stages (>= 0).
        threads: torch threads (0: torch's default).
        device: where Stage 1 and Stage 2 train (``auto``: cuda when available).
        progress: progress bars.
        log: also write the stage's output to this file.
        variant: a name of ``variants``, merged in; ``variants``: ``{name: settings delta}``.
        ablation: a key of ``ablations``; ``ablations``: ``{key: [variant names]}``.
        ablation_seeds: ``None``: one run per variant (the run's seed); a list: each
            variant's Stage 2 once per seed (``<variant>@seed<k>``), its row the median.
    """

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
    ablations: dict[str, list[str]] = field(default_factory=dict)
    ablation_seeds: Optional[list[int]] = None


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
    "extrapolation": ExtrapolationConfig,
    "deformation": DeformationCompareConfig,
    "gp2d": GP2DConfig,
    "robot_figures": RobotFigureConfig,
    "view": ViewConfig,
    "render": RenderConfig,
    "table": TableConfig,
    "seed_table": SeedTableConfig,
    "krauss_table": KraussTableConfig,
}
"""Group name -> its dataclass; the top-level keys are :class:`RunConfig`'s."""

NESTED: dict[str, type] = {"diagnose.where": WhereConfig, "diagnose.refit": RefitConfig}
"""Groups nested in another group's dataclass (listed so that the registry names every settings class)."""


# ----------------------------------------------------------------------------- Hydra ConfigStore
def _omegaconf_type(tp: Any) -> Any:
    """The nearest annotation OmegaConf's structured configs accept (it has no ``Literal``: the choices
    are checked by :func:`validate_config`)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        return str
    if origin is Union or origin is types.UnionType:
        inner = [a for a in args if a is not type(None)]
        return Optional[_omegaconf_type(inner[0])] if len(inner) == 1 and not dataclasses.is_dataclass(inner[0]) else Any
    if tp in (list, tuple) or origin in (list, tuple, Sequence):
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

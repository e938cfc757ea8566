"""Command line: ``python -m lagsplat <stage> system=<name> [hydra overrides]``.

One stage per Snakemake rule (:mod:`lagsplat.stages`, :mod:`lagsplat.stages_report`, :mod:`lagsplat.stages_baselines`,
:mod:`lagsplat.stages_deformation`); each reads only upstream artifacts under
``${results_dir}/${system.name}/`` and writes its own atomically, with the
resolved configuration saved beside it (``config/<stage>.yaml``).

Stages: ``download``, ``ingest``, ``stage1``, ``chart``, ``stage2``,
``evaluate``, ``figures``, ``forces``, ``export``, ``diagnose``, ``extrapolation``, ``extrapolation_table``, ``deformation``, ``table``, ``ablation``, ``krauss_table``,
``seed_table``, ``views_table``, ``all`` (ingest ->
figures in one process), and ``view`` (the interactive viewer, which writes
nothing).
"""

from __future__ import annotations

import inspect
import sys
import time
import warnings
from pathlib import Path
from typing import Callable

from omegaconf import DictConfig

from lagsplat.cli_common import apply_variant, clear_stop, compose, find_conf_dir, record_stop
from lagsplat.stages import stage_chart, stage_download, stage_evaluate, stage_figures, stage_ingest, stage_stage1, stage_stage2, stage_views
from lagsplat.stages_baselines import stage_extrapolation, stage_extrapolation_table
from lagsplat.stages_deformation import stage_deformation
from lagsplat.stages_report import stage_ablation, stage_diagnose, stage_export, stage_forces, stage_krauss_table, stage_robot_figures, stage_render, stage_seed_table, stage_table, stage_view, stage_views_table

__all__ = ["main", "STAGES", "stage_all", "stage_help", "run_logged"]

USAGE = """usage: python -m lagsplat <stage> system=<name> [key=value ...]

stages:
  download   fetch the system's source clip (URL + SHA256 from conf/system/<name>.yaml)
  ingest     source clip -> results/<name>/clip.npz
  views      clip.npz -> views/ (3-D systems: cached novel views of every frame and their cameras; system.views)
  stage1     clip.npz -> stage1.pt           (encoder + conditioned-Gaussian decoder)
  chart      stage1.pt -> chart.npz          (whitening, G_bar, A, AE floor)
  stage2     chart.npz -> stage2.pt          (latent Lagrangian)
  evaluate   -> metrics.json                 (eps_freq, eps_q, eps_I / eps_AE; system.protocol=krauss:
             the published soft-robot protocol, lagsplat.evaluate.krauss)
  figures    -> figures/rollout.png
  forces     -> forces.json, figures/forces.png (force-transport checks: background, linearity, kernel)
  export     -> export/: the identified model for use outside lagsplat (docs/export.md): dynamics.py (NumPy,
             rhs for scipy's solve_ivp) + weights.npz, TorchScript M/V/C(/b).pt, model.json, trajectory.csv,
             rollout.csv, splat_q_<k>.ply (the decoder at chosen states, standard 3DGS layout)
  diagnose   -> diagnosis/report.md, report.json, figures/ (sim-to-real gap: which unmodelled effect,
             where it shows, held-out gap before / after a Stage-2 refit with it; lagsplat.diagnose)
  table      metrics.json of table.systems -> results/tables/<table.name>.tex/.csv
  ablation   variants' metrics.json of one system -> results/tables/<name>_<ablation>.tex/.csv
  extrapolation  -> extrapolation.json: LaGSplat, a latent neural ODE (no prior) and GP-2D (GaussianPrediction's
             structure in 2-D) predict the held-out frames and 1000 s past them (paper §4.3; lagsplat.baselines)
  extrapolation_table  extrapolation.json of table.systems -> results/tables/extrapolation.tex/.csv/.md
  deformation  the conditioned decoder against a deformation-field decoder at equal budget (paper App. B):
             trains variants/deformation/stage1.pt -> results/tables/deformation.tex/.csv/.json, figures/deformation.png
  robot_figures  -> figures/robot_rollout.png (30 s pressure-driven rollout decoded at 256x256) and
             figures/robot_forces.png, robot_forces.json (force equilibria at the operating pressure; paper §4.4-4.5)
  krauss_table  soft-robot benchmark (paper Table 4) -> results/tables/krauss.tex/.csv/.md
  seed_table one system trained with each of seed_table.seeds (results/seeds/seed<k>/<name>/metrics.json)
             -> results/tables/<name>_seeds.md/.csv (per-seed rows, mean, std, min, max)
  views_table  metrics.json of the 3-D systems of table.systems -> results/tables/<table.name>.csv/.md (PSNR of the
             training views and of the held-out cameras; paper §3.2, App. C)
  all        ingest (.. views) .. figures for one system
  render     a 3-D model's novel views -> figures/novel_views.mp4, .png (render.camera=orbit|<cameras.json>,
             render.rollout_s: along a free rollout)
  view       interactive viewer: drag the identified model in a local web page
             (http://127.0.0.1:<view.port>/; settings in the `view` group of conf/config.yaml)

  variant=<name> (see `variants` in conf/config.yaml) runs stage2 / evaluate / figures
  as an ablation on the same frozen chart, into results/<name>/variants/<variant>/.

examples:
  python -m lagsplat all system=toy
  python -m lagsplat stage1 system=oscillating_cart stage1.steps=500
  python -m lagsplat table table.name=physical 'table.systems=[toy,oscillating_cart]'
  python -m lagsplat stage2 system=two_carts variant=mass_decoder
  python -m lagsplat view system=toy view.port=0
"""


def stage_all(cfg: DictConfig) -> None:
    """Run ingest .. figures for one system in this process."""
    names = ("ingest", "views", "stage1", "chart", "stage2", "evaluate", "figures")
    for name in names if cfg.system.get("views") else [n for n in names if n != "views"]:
        t0 = time.time()
        try:
            STAGES[name](cfg)
        except Exception as exc:
            exc.lagsplat_stage = name  # the stage that stopped, for its stop record (main)
            raise
        clear_stop(cfg, name)
        print(f"[lagsplat] {cfg.system.name}: {name} done in {time.time() - t0:.1f} s", flush=True)



STAGES: dict[str, Callable[[DictConfig], None]] = {
    "download": stage_download,
    "ingest": stage_ingest,
    "views": stage_views,
    "stage1": stage_stage1,
    "chart": stage_chart,
    "stage2": stage_stage2,
    "evaluate": stage_evaluate,
    "figures": stage_figures,
    "forces": stage_forces,
    "export": stage_export,
    "diagnose": stage_diagnose,
    "table": stage_table,
    "ablation": stage_ablation,
    "extrapolation": stage_extrapolation,
    "extrapolation_table": stage_extrapolation_table,
    "deformation": stage_deformation,
    "krauss_table": stage_krauss_table,
    "robot_figures": stage_robot_figures,
    "seed_table": stage_seed_table,
    "views_table": stage_views_table,
    "all": stage_all,
    "view": stage_view,
    "render": stage_render,
}



def stage_help(stage: str) -> str:
    """The help of one stage: its usage line, its entry in :data:`USAGE` and its docstring."""
    lines = USAGE.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(f"  {stage} "))
    end = start + 1
    while end < len(lines) and lines[end].startswith("             "):
        end += 1
    entry = lines[start:end]
    doc = inspect.cleandoc(STAGES[stage].__doc__ or "")
    return (
        f"usage: python -m lagsplat {stage} system=<name> [key=value ...]\n\n"
        + "\n".join(entry) + "\n\n" + doc + "\n\n"
        "Every key of conf/config.yaml and conf/system/<name>.yaml can be set as key=value (Hydra overrides)."
    )


class _Tee:
    """A text stream that writes to the terminal stream and to a log file."""

    def __init__(self, stream, log) -> None:
        self.stream, self.log = stream, log

    def write(self, text: str) -> int:
        self.log.write(text)
        self.log.flush()
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()
        self.log.flush()

    def isatty(self) -> bool:
        return self.stream.isatty()

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


def run_logged(stage: str, cfg: DictConfig) -> None:
    """Run ``STAGES[stage](cfg)``; with ``cfg.log`` set, its stdout and stderr also go to that file (created, truncated)."""
    log_path = cfg.get("log")
    if not log_path:
        STAGES[stage](cfg)
        return
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "w", encoding="utf-8") as log:
        log.write(f"lagsplat {stage} system={cfg.system.name}: started {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        out, err = sys.stdout, sys.stderr
        sys.stdout, sys.stderr = _Tee(out, log), _Tee(err, log)
        t0 = time.perf_counter()
        try:
            STAGES[stage](cfg)
        except BaseException as exc:
            log.write(f"lagsplat {stage}: {type(exc).__name__}: {exc}\n")
            raise
        finally:
            sys.stdout, sys.stderr = out, err
        log.write(f"lagsplat {stage} system={cfg.system.name}: done in {time.perf_counter() - t0:.1f} s\n")


def main(argv: list[str] | None = None) -> int:
    """Entry point. Returns the process exit code (0 ok, 1 error, 2 usage).

    A pipeline stage (:data:`lagsplat.artifacts.STOP_STAGES`) that stops with a one-line
    ``ValueError`` (a ``ClipError`` from ingest, Stage 2 refusing a chart that failed the
    quality gate, ...) leaves ``stopped.json`` ``{stage, reason, time}`` beside its output
    (:func:`lagsplat.cli_common.record_stop`); the stage's next success removes it. The
    ``diagnose`` stage then writes a ``cannot_diagnose`` report with that reason and exits 0.
    """
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(USAGE)
        return 0 if argv else 2
    stage, overrides = argv[0], argv[1:]
    if stage not in STAGES:
        print(f"lagsplat: unknown stage {stage!r}\n\n{USAGE}", file=sys.stderr)
        return 2
    if any(a in ("-h", "--help") for a in overrides):
        print(stage_help(stage))
        return 0
    from lagsplat.io.clip import ClipError
    from lagsplat.io.download import DownloadError

    cfg, running = None, False
    try:
        from lagsplat.config_check import ConfigError, validate_config

        cfg = compose(overrides)
        try:
            validate_config(cfg)  # a bad value stops here, before any work, naming key and value
        except ConfigError as exc:
            print(f"lagsplat {stage}: configuration error: {exc}", file=sys.stderr)
            return 1
        cfg = apply_variant(cfg)  # its settings were checked with the variants
        if "device" in cfg:  # a bad or unavailable device fails here, before any work
            from lagsplat.train.device import resolve_device

            resolve_device(str(cfg.device))
        if int(cfg.threads) > 0:
            import torch

            torch.set_num_threads(int(cfg.threads))
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Converting a tensor with requires_grad=True to a scalar")
            running = True
            run_logged(stage, cfg)
        clear_stop(cfg, stage)  # a stage that succeeds undoes its own stop record (and any downstream of it)
    except (ClipError, DownloadError, FileNotFoundError, KeyError, ValueError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        print(f"lagsplat {stage}: error: {msg}", file=sys.stderr)
        if running and isinstance(exc, ValueError):  # the clip or the chart refused (not a missing upstream file):
            record_stop(cfg, getattr(exc, "lagsplat_stage", stage), msg)  # results/<system>/stopped.json, read by diagnose
        return 1
    except Exception as exc:  # hydra config errors etc.
        if type(exc).__module__.startswith(("hydra", "omegaconf")):
            from lagsplat.config_check import explain_compose_error

            print(f"lagsplat {stage}: configuration error: {explain_compose_error(exc, overrides, find_conf_dir())}", file=sys.stderr)
            return 1
        raise
    return 0

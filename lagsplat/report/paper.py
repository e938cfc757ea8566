"""What the paper target builds: every table and figure of the paper this project can make offline.

One list, :func:`paper_items`, read by the Snakemake target ``paper`` (``workflow/rules/paper.smk``: its inputs)
and by the results page (:mod:`lagsplat.report.results_page`: one section per paper part, a Markdown table per
CSV, an image per figure). Each item names the paper's table or figure it stands for:

* §4.2, Table 2 and Figs. rainbow-rollout / sac-rollout: the free rollouts of the toy, the oscillating cart and
  the apple pendulum (the main runs, seed 0), each system again at every seed of ``seed_table.seeds``, and the
  rollout figure of each;
* §4.3, Table 3 and Fig. 5 (rainbow-equilibrium): the extrapolation against a latent neural ODE and GP-2D;
* §4.4, Table 4 and Figs. krauss-npz-rollout / krauss-force: the soft robot on the offline surrogate, one and
  two segments;
* §4.5, Fig. rainbow-force: the force-transport figure of the oscillating cart;
* §3.2 / App. C and Fig. rainbow-3d: the 3-D pendulum's PSNR on the held-out cameras and an orbit of novel views;
* App. B, Fig. deform-velocity: the conditioned decoder against a deformation-field decoder at equal budget;
* the sim-to-real gap diagnosis of the oscillating cart (no paper counterpart: the project's own report).

Paths come from :mod:`lagsplat.artifacts` (the one module that spells a file name); ``results_dir`` is the
Snakemake ``results_dir``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from lagsplat.artifacts import Artifacts, table_path

__all__ = [
    "PaperItem",
    "paper_items",
    "PHYSICAL_SYSTEMS",
    "SEED_SYSTEMS",
    "KRAUSS_SURROGATE",
    "KRAUSS_SURROGATE_TABLE",
    "VIEWS_SYSTEM",
    "VIEWS_TABLE",
    "FORCES_SYSTEM",
    "DIAGNOSIS_SYSTEM",
    "DEFORMATION_SYSTEM",
]

PHYSICAL_SYSTEMS = ("toy", "oscillating_cart", "red_apple_pendulum")
"""The systems of the Table 2 analogue (the Snakefile's ``TABLES["physical"]``) and of the extrapolation table."""

SEED_SYSTEMS = PHYSICAL_SYSTEMS
"""The systems trained once per seed of ``seed_table.seeds`` (``<system>_seeds.csv``)."""

KRAUSS_SURROGATE = {"1seg": "krauss_1seg_synth", "2seg": "krauss_2seg_synth"}
"""The offline surrogate of the soft robot (lagsplat.synth.continuum_robot), one and two segments."""

KRAUSS_SURROGATE_TABLE = "krauss_surrogate"
"""The soft-robot table on the surrogate, whatever ``krauss_source`` says (workflow/rules/krauss.smk)."""

VIEWS_SYSTEM = "pendulum3d"
"""The synthetic 3-D system whose held-out cameras are scored."""

VIEWS_TABLE = "novel_views"
"""Its PSNR table (``python -m lagsplat views_table``)."""

FORCES_SYSTEM = "oscillating_cart"
DIAGNOSIS_SYSTEM = "oscillating_cart"
DEFORMATION_SYSTEM = "oscillating_cart"


@dataclass(frozen=True)
class PaperItem:
    """One table, figure or report of the paper target.

    Attributes:
        key: a short unique name (the copied image's file name, the page's anchor).
        kind: ``table`` (a CSV), ``figure`` (a PNG) or ``report`` (a Markdown report and its JSON record beside it).
        path: the file the pipeline writes and the page reads.
        target: the Snakemake target that builds it (``snakemake -c2 <target>``).
        section: the paper part it reproduces, the page's heading.
        caption: one line under it on the page.
    """

    key: str
    kind: str
    path: str
    target: str
    section: str
    caption: str

    @property
    def command(self) -> str:
        """The command that builds the item alone."""
        return f"snakemake -c2 {self.target}"


S42 = "Free rollouts (paper §4.2, Table 2)"
S43 = "What the Lagrangian prior buys: extrapolation (paper §4.3, Table 3, Fig. 5)"
S44 = "Soft robot on the offline surrogate (paper §4.4, Table 4, Figs. krauss-npz-rollout and krauss-force)"
S45 = "Applying forces (paper §4.5, Fig. rainbow-force)"
S3D = "Novel views of the 3-D pendulum (paper §3.2 and §4.5, Fig. rainbow-3d)"
SAB = "Deformation-field decoder at equal budget (paper App. B, Fig. deform-velocity)"
SDG = "Sim-to-real gap diagnosis (the project's own report)"


def paper_items(results_dir: str | Path = "results") -> list[PaperItem]:
    """Every item of the paper target, in the page's order (module docstring)."""
    res = Path(results_dir)

    def art(system: str) -> Artifacts:
        return Artifacts.at(res / system)

    def table(key: str, name: str, section: str, caption: str, target_suffix: str = ".tex") -> PaperItem:
        return PaperItem(key, "table", str(table_path(res, name, ".csv")), str(table_path(res, name, target_suffix)), section, caption)

    def figure(key: str, path: Path, section: str, caption: str) -> PaperItem:
        return PaperItem(key, "figure", str(path), str(path), section, caption)

    items = [table("physical", "physical", S42, "The held-out scores of the main runs (seed 0): eps_freq (%), eps_q, eps_I / eps_AE, eps_AE (1e-4).")]
    items += [table(f"seeds_{s}", f"{s}_seeds", S42, f"{s}: one row per seed of seed_table.seeds (mean and spread in the .md beside the CSV).", ".md")
              for s in SEED_SYSTEMS]  # fmt: skip
    items += [figure(f"rollout_{s}", art(s).rollout_figure, S42, f"{s}: one free rollout across the train / held-out boundary.") for s in PHYSICAL_SYSTEMS]
    items.append(table("extrapolation", "extrapolation", S43, "LaGSplat, a latent neural ODE and GP-2D on the held-out frames and far past the clip."))
    items += [figure(f"extrapolation_{s}", art(s).extrapolation_figure, S43, f"{s}: free extrapolation far past the clip, every model read in one chart.")
              for s in PHYSICAL_SYSTEMS]  # fmt: skip
    items.append(table("krauss_surrogate", KRAUSS_SURROGATE_TABLE, S44, "Published rows and ours on the surrogate robot, one and two segments, with the inertia ablation."))
    for seg, s in KRAUSS_SURROGATE.items():
        a = art(s)
        items.append(figure(f"robot_rollout_{seg}", a.robot_rollout_figure, S44, f"{s}: a pressure-driven free rollout on the held-out split."))
        items.append(figure(f"robot_forces_{seg}", a.robot_forces_figure, S44, f"{s}: loaded equilibria at the operating pressure."))
    items.append(figure("forces", art(FORCES_SYSTEM).forces_figure, S45, f"{FORCES_SYSTEM}: force transport J^T f, background, linearity and kernel checks."))
    items.append(table("novel_views", VIEWS_TABLE, S3D, f"{VIEWS_SYSTEM}: PSNR of the training views and of the held-out cameras (never trained on).", ".csv"))
    items.append(figure("novel_views_orbit", art(VIEWS_SYSTEM).novel_views_figure, S3D, f"{VIEWS_SYSTEM}: the state of the first held-out frame seen from an orbit of cameras."))
    items.append(table("deformation", "deformation", SAB, f"{DEFORMATION_SYSTEM}: the conditioned decoder against a deformation-field decoder at equal budget."))
    items.append(figure("deformation_velocity", art(DEFORMATION_SYSTEM).deformation_figure, SAB, f"{DEFORMATION_SYSTEM}: the two decoders' velocity fields at one state."))
    rep = art(DIAGNOSIS_SYSTEM).report_md
    items.append(PaperItem("diagnosis", "report", str(rep), str(rep), SDG, f"{DIAGNOSIS_SYSTEM}: which unmodelled effect, where it shows, and the held-out gap after a refit."))
    keys = [it.key for it in items]
    if len(set(keys)) != len(keys):
        raise ValueError(f"paper items share a key: {keys}")
    return items

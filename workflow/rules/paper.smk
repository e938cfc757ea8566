# The paper target: every table and figure of the paper the project can make offline, then the results page.
#
#   snakemake -c2 paper                                   # all of it -> docs/results.md, docs/results/*.png
#   snakemake -n -c2 paper                                # the jobs, run nothing
#   snakemake -c2 paper --config raw_dir=/path/to/clips   # the real clips (oscillating cart, apple) kept elsewhere
#   snakemake --profile profiles/slurm paper              # one SLURM job per job of the DAG; the page on the login node
#   python -m lagsplat.report.results_page                # the page again from whatever is built (missing items listed)
#
# The items (lagsplat.report.paper.paper_items, each with the paper table or figure it stands for): the Table 2
# analogue (results/tables/physical.csv) and the same three systems at every seed of seed_table.seeds
# (<system>_seeds.csv, seed_run / seed_table), their rollout figures; the extrapolation table and figures
# (§4.3); the soft-robot table on the surrogate (krauss_surrogate, one and two segments) and both robots' two
# figures (§4.4); the force figure (§4.5); the 3-D pendulum's held-out-camera PSNR (views_table) and an orbit of
# novel views (render); the deformation-field comparison (App. B); one diagnosis report. Before the first job, the
# projected wall time on the cores given, item by item (lagsplat.report.projection.project_items; onstart in the
# Snakefile).
import shlex

from lagsplat.report.paper import DEFORMATION_SYSTEM as _PAPER_DEFORMATION, SEED_SYSTEMS as PAPER_SEED_SYSTEMS, VIEWS_SYSTEM, VIEWS_TABLE, paper_items

PAPER_ITEMS = paper_items(RESULTS)
PAPER_PAGE = "docs/results.md"
PAPER_IMAGES = "docs/results"
if _PAPER_DEFORMATION != DEFORMATION_SYSTEM or tuple(TABLES["physical"]) != tuple(EXTRAPOLATION_SYSTEMS):
    raise ValueError("lagsplat.report.paper and the rules disagree on the systems of the deformation or the physical table")


rule render:
    """A 3-D model's novel views (paper §4.5, Fig. rainbow-3d): the encoded state of the first held-out frame seen
    from an orbit of cameras -> figures/novel_views.mp4 and the contact sheet figures/novel_views.png."""
    input:
        clip=str(ART.clip),
        stage1=str(ART.stage1),
        chart=str(ART.chart),
        stage2=str(ART.stage2),  # read for a rollout (render.rollout_s > 0)
        views=str(ART.views),
    output:
        novel_views_video=str(ART.novel_views_video),
        novel_views_figure=str(ART.novel_views_figure),
    log:
        f"{RESULTS}/logs/{{system}}/render.log",
    threads: 1
    shell:
        cli("render", ["clip", "stage1", "chart", "stage2", "views"], ["novel_views_video", "novel_views_figure"])


rule views_table:
    """The 3-D pendulum's PSNR on its training views and on the held-out cameras (paper §3.2, App. C), from its
    metrics.json -> results/tables/novel_views.csv and .md."""
    input:
        table_inputs=[str(ART.metrics).format(system=VIEWS_SYSTEM)],
    output:
        table_csv=f"{RESULTS}/tables/{VIEWS_TABLE}.csv",
        table_md=f"{RESULTS}/tables/{VIEWS_TABLE}.md",
    log:
        f"{RESULTS}/logs/tables/{VIEWS_TABLE}.log",
    params:
        table_inputs=joined("table_inputs"),
    threads: 1
    shell:
        cli("views_table", outputs=["table_csv", "table_md"], lists=["table_inputs"], system=None,
            extra=f"table.name={VIEWS_TABLE} 'table.systems=[{VIEWS_SYSTEM}]'")


rule results_page:
    """docs/results.md: each table of the paper target re-rendered from its CSV with the command that built it, each
    figure as a reduced copy in docs/results/ (lagsplat.report.results_page); the paper target's last step."""
    input:
        [it.path for it in PAPER_ITEMS],
    output:
        page=PAPER_PAGE,
        images=directory(PAPER_IMAGES),
    log:
        f"{RESULTS}/logs/paper/results_page.log",
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    shell:
        f"python -m lagsplat.report.results_page --results {RESULTS} --page {{output.page}} --images {{output.images}} > {{log}} 2>&1"


rule paper:
    """Every table and figure of the paper the project can make offline, and the results page that shows them. The
    items are inputs of their own: a page already there (committed) does not stand for them, as Snakemake would
    otherwise leave the missing inputs of an existing output unbuilt; once they are built, the page is older and
    is written again."""
    input:
        [it.path for it in PAPER_ITEMS],
        PAPER_PAGE,


localrules:
    results_page,
    paper,


def _paper_job_system(job):
    """The system whose configuration prices a job (its wildcard, the surrogate's file, the decoder comparison's), or None."""
    w = dict(job.wildcards)
    if "system" in w:
        return w["system"]
    if job.rule.name == "deformation_table":
        return DEFORMATION_SYSTEM
    return _KSYN.get(w.get("file"))


def _paper_projection():
    """Print the projected wall time of the paper target's planned jobs, item by item, before the first one starts
    (lagsplat.report.projection.project_items): each job counts under the first item that needs it. Returns whether
    the plan holds the paper target (nothing printed otherwise)."""
    from lagsplat.cli_common import apply_variant, compose
    from lagsplat.report.projection import item_lines, project_items

    dag = workflow.dag
    if not any(j.rule.name == "results_page" for j in dag.needrun_jobs()):
        return False
    producer = {str(f): j for j in dag.jobs for f in j.output}
    base = [f"raw_dir={RAW}", f"results_dir={RESULTS}", *shlex.split(OVR)]
    cfgs, seen, items = {}, set(), {}
    for it in PAPER_ITEMS + [None]:  # None: what only the page needs (the page itself)
        todo = [producer[it.path]] if it is not None and it.path in producer else [j for j in dag.needrun_jobs() if j not in seen]
        jobs = []
        while todo:
            j = todo.pop()
            if j in seen:
                continue
            seen.add(j)
            todo.extend(dag.dependencies[j])
            if not dag.needrun(j) or j.rule.norun:  # done already, or a target that runs nothing
                continue
            system, w = _paper_job_system(j), dict(j.wildcards)
            key = (system, w.get("variant"))
            if system is not None and key not in cfgs:  # one composition per system and variant, not per job
                cfgs[key] = apply_variant(compose([f"system={system}", *base] + ([f"variant={key[1]}"] if key[1] else [])))
            lane = f"seed{w['seed']}/{system}" if "seed" in w else str(system)
            jobs.append((j.rule.name, lane, cfgs.get(key) if system is not None else None, j.threads))
        items[it.key if it is not None else "results page"] = jobs
    for line in item_lines(project_items(items, workflow.resource_settings.cores or 1)):
        print(line, flush=True)
    return True

"""The multi-run Snakemake targets (blind diagnosis suite, seeds, the physical table, the paper), dry-run as a user would.

Each target must plan one job per run, every job with a log file its output is
redirected to, so that ``--cores N`` or the SLURM profile runs the runs in
parallel. The SLURM profile is dry-run with SLURM's commands replaced by
stubs that fail: planning needs no cluster and submits nothing. The suite's
scoring rule (``benchmarks/diagnosis.py --gather``) is run on hand-made rows.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from lagsplat.diagnose.refit import GAP_METRICS
from lagsplat.report.paper import KRAUSS_SURROGATE, SEED_SYSTEMS, paper_items
from lagsplat.synth.effect_clips import blind_suite

ROOT = Path(__file__).resolve().parents[1]
SLURM_PLUGIN = importlib.util.find_spec("snakemake_executor_plugin_slurm") is not None
SLURM_COMMANDS = ("sbatch", "srun", "squeue", "sacct", "sinfo", "scontrol", "sacctmgr", "scancel")
PROFILES = [
    pytest.param([], id="default"),
    pytest.param(["--profile", "profiles/local"], id="local"),
    pytest.param(
        ["--profile", "profiles/slurm"],
        id="slurm",
        marks=pytest.mark.skipif(not SLURM_PLUGIN, reason="needs pip install snakemake-executor-plugin-slurm"),
    ),
]


@pytest.fixture
def slurm_stubs(tmp_path) -> tuple[dict, Path]:
    """``(env, calls)``: PATH led by stubs of SLURM's commands that append their command line to ``calls`` and fail."""
    bindir, calls = tmp_path / "slurm_bin", tmp_path / "slurm_calls"
    bindir.mkdir()
    for cmd in SLURM_COMMANDS:
        stub = bindir / cmd
        stub.write_text(f'#!/bin/sh\necho {cmd} "$@" >> "{calls}"\nexit 1\n')
        stub.chmod(0o755)
    return dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ['PATH']}"), calls


def dry_run(args: list[str], env: dict | None = None) -> subprocess.CompletedProcess:
    """``snakemake -n -p <args>`` in the project root; stdout and stderr together in ``stdout``."""
    return subprocess.run(
        ["snakemake", "-n", "-p", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300
    )


def job_counts(out: str) -> dict[str, int]:
    """Rule -> planned jobs, from the dry run's ``Job stats`` table."""
    table = out.split("Job stats:", 1)[1].split("total", 1)[0]
    return {m.group(1): int(m.group(2)) for m in re.finditer(r"^(\w+)\s+(\d+)\s*$", table, re.M)}


def jobs(out: str) -> list[dict[str, str]]:
    """The planned jobs of a dry run with ``-p``: ``rule``, the printed keys (``log``, ``wildcards``, ``resources``, ...) and ``shell``."""
    found: list[dict[str, str]] = []
    for line in out.splitlines():
        m = re.match(r"^(?:local)?rule (\w+):$", line)
        if m:
            found.append({"rule": m.group(1)})
        elif found and (m := re.match(r"^    (\w+): (.*)$", line)):
            found[-1][m.group(1)] = m.group(2)
        elif found and line.startswith("Shell command: "):
            found[-1]["shell"] = line[len("Shell command: ") :]
    return found


def assert_logged(job: dict[str, str]) -> None:
    """The job has a log file and its command writes it: its stdout and stderr are redirected there (downloads
    repeat it on stderr when they fail), or a per-system stage gets ``log=<file>`` and writes the log itself
    while its output also reaches the screen; such a stage also gets its input and output paths."""
    assert job.get("log"), job
    log, shell = job["log"], job["shell"]
    ends = (f"> {log} 2>&1", f"> {log} 2>&1 || {{ cat {log} >&2; exit 1; }}")
    if shell.startswith("python -m lagsplat ") and f" log={log} " in shell + " ":
        for path in job.get("output", "").split(","):
            assert not path.strip() or f"={path.strip()}" in shell or "/diagnosis/" in path, (path, shell)
        return
    assert shell.endswith(ends), job


@pytest.mark.parametrize("profile", PROFILES)
def test_the_blind_suite_plans_one_logged_job_per_clip(tmp_path, slurm_stubs, profile):
    env, calls = slurm_stubs
    res = tmp_path / "res"
    r = dry_run([*profile, "suite", "--config", f"results_dir={res}"], env=env)
    assert r.returncode == 0, r.stdout
    names = [e["name"] for e in blind_suite(2)]
    assert job_counts(r.stdout) == {"suite_clip": len(names), "suite_summary": 1, "suite": 1}
    planned = jobs(r.stdout)
    clips = [j for j in planned if j["rule"] == "suite_clip"]
    assert sorted(j["wildcards"] for j in clips) == sorted(f"budget=cheap, clip={n}" for n in names)
    for j in clips:
        assert_logged(j)
        name = j["wildcards"].split("clip=")[1]
        assert f"benchmarks/diagnosis.py --clip {name} --budget cheap " in j["shell"]
        assert f"--results {res}/diagnosis_bench " in j["shell"] and f"--row {res}/benchmarks/diagnosis/cheap/{name}.json" in j["shell"]
        assert "mem_mb=4000" in j["resources"] and "runtime=30" in j["resources"]
    (summary,) = [j for j in planned if j["rule"] == "suite_summary"]
    assert_logged(summary)
    assert summary["output"] == f"{res}/benchmarks/diagnosis_cheap.md, {res}/benchmarks/diagnosis_cheap.json"
    assert summary["shell"].startswith("python benchmarks/diagnosis.py --gather ")
    assert all(f"{res}/benchmarks/diagnosis/cheap/{n}.json" in summary["shell"] for n in names)
    if "profiles/slurm" in profile:
        assert "slurm_partition=" in clips[0]["resources"]
    # planning queries no more than the cluster's configuration, and submits nothing
    called = calls.read_text().splitlines() if calls.exists() else []
    assert not [c for c in called if c.split()[0] in ("sbatch", "srun", "scancel")], called


def test_the_suite_follows_blind_suite_and_the_budget(tmp_path):
    res = tmp_path / "res"
    r = dry_run(["suite", "--config", f"results_dir={res}", "suite_n_per_effect=1", "suite_budget=standard", "suite_args=--dof-refit"])
    assert r.returncode == 0, r.stdout
    names = [e["name"] for e in blind_suite(1)]
    assert job_counts(r.stdout)["suite_clip"] == len(names) < len(blind_suite(2))
    clips = [j for j in jobs(r.stdout) if j["rule"] == "suite_clip"]
    assert {j["wildcards"].split("clip=")[1] for j in clips} == set(names)
    assert all("--budget standard --n-per-effect 1 " in j["shell"] and "--dof-refit" in j["shell"] and "runtime=180" in j["resources"] for j in clips)
    assert f"{res}/benchmarks/diagnosis_standard.md" in r.stdout
    # a single clip is a target of its own
    one = dry_run([f"{res}/benchmarks/diagnosis/cheap/{names[0]}.json", "--config", f"results_dir={res}"])
    assert one.returncode == 0 and job_counts(one.stdout) == {"suite_clip": 1}, one.stdout


@pytest.mark.parametrize("profile", PROFILES)
def test_seeds_plan_one_logged_job_per_system_and_seed(tmp_path, slurm_stubs, profile):
    env, calls = slurm_stubs
    res, raw = tmp_path / "res", tmp_path / "raw"
    r = dry_run([*profile, "seeds", "--config", f"results_dir={res}", f"raw_dir={raw}", "seeds=0,1,2,3", "seed_systems=toy,oscillating_cart"], env=env)
    assert r.returncode == 0, r.stdout
    # the real clip is downloaded once, for all its seeds
    assert job_counts(r.stdout) == {"seed_run": 8, "seed_table": 2, "seeds": 1, "download": 1}
    planned = jobs(r.stdout)
    runs = [j for j in planned if j["rule"] == "seed_run"]
    assert sorted(j["wildcards"] for j in runs) == sorted(f"seed={k}, system={s}" for k in range(4) for s in ("toy", "oscillating_cart"))
    for j in runs:
        assert_logged(j)
        seed, system = re.match(r"seed=(\d+), system=(\w+)", j["wildcards"]).groups()
        assert f"python -m lagsplat all system={system} " in j["shell"]
        assert f"results_dir={res}/seeds/seed{seed} " in j["shell"] and f" seed={seed} >" in j["shell"]
        assert f"{res}/seeds/seed{seed}/{system}/metrics.json" in j["output"]
        assert "mem_mb=8000" in j["resources"] and "runtime=240" in j["resources"]
    tables = [j for j in planned if j["rule"] == "seed_table"]
    for j in tables:
        assert_logged(j)
        assert "'seed_table.seeds=[0,1,2,3]'" in j["shell"]
    assert sorted(j["output"].split(",")[0] for j in tables) == [f"{res}/tables/oscillating_cart_seeds.md", f"{res}/tables/toy_seeds.md"]
    called = calls.read_text().splitlines() if calls.exists() else []
    assert not [c for c in called if c.split()[0] in ("sbatch", "srun", "scancel")], called


def test_per_job_threads_are_what_the_rules_declare(tmp_path):
    # a dry run with 8 cores shows each job's threads (capped by the cores given)
    r = dry_run(["-c8", "seeds", "suite", "--config", f"results_dir={tmp_path}"])
    assert r.returncode == 0, r.stdout
    planned = jobs(r.stdout)
    assert {j.get("threads", "1") for j in planned if j["rule"] == "seed_run"} == {"2"}
    assert {j.get("threads", "1") for j in planned if j["rule"] == "suite_clip"} == {"1"}
    assert all(f"NUMBA_NUM_THREADS={j.get('threads', '1')} " in j["shell"] for j in planned if j["rule"] in ("seed_run", "suite_clip"))


def test_every_rule_that_runs_a_command_has_a_log():
    r = subprocess.run(["snakemake", "--lint"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
    assert "Lints for rule suite_clip" in r.stdout, r.stdout  # the linter read the included rules
    assert "No log directive defined" not in r.stdout, r.stdout


def test_every_planned_job_sends_its_output_to_its_log(tmp_path):
    res, raw = tmp_path / "res", tmp_path / "raw"
    targets = [f"{res}/tables/physical.tex", f"{res}/tables/two_carts_inertia.tex", f"{res}/toy/forces.json", f"{res}/toy/diagnosis/report.md",
               f"{res}/tables/deformation.tex", f"{res}/tables/extrapolation.tex"]  # fmt: skip
    r = dry_run([*targets, "krauss", "--config", f"results_dir={res}", f"raw_dir={raw}", "krauss_source=synthetic"])
    assert r.returncode == 0, r.stdout
    planned = [j for j in jobs(r.stdout) if j["rule"] not in ("krauss",)]  # a target rule runs nothing
    rules = {j["rule"] for j in planned}
    assert rules >= {"download", "ingest", "stage1", "chart", "stage2", "evaluate", "figures", "table", "stage2_variant", "evaluate_variant",
                     "ablation_table", "forces", "diagnose", "krauss_synth", "krauss_table", "deformation_table", "extrapolation",
                     "extrapolation_table", "robot_figures"}  # fmt: skip
    for j in planned:
        assert_logged(j)
    real = dry_run(["krauss", "--config", f"results_dir={res}", f"raw_dir={raw}"])
    assert real.returncode == 0, real.stdout
    for j in jobs(real.stdout):
        if j["rule"] in ("krauss_archive", "krauss_extract"):
            assert_logged(j)
    assert {"krauss_archive", "krauss_extract"} <= {j["rule"] for j in jobs(real.stdout)}


def test_the_physical_table_runs_its_systems_in_parallel(tmp_path):
    # the DAG of the table: removing the table job leaves one chain per system, sharing no job
    res, raw = tmp_path / "res", tmp_path / "raw"
    r = subprocess.run(
        ["snakemake", f"{res}/tables/physical.tex", "--config", f"results_dir={res}", f"raw_dir={raw}", "--dag", "dot"],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    labels = {int(i): lab for i, lab in re.findall(r"^\s*(\d+)\[label = \"([^\"]+)\"", r.stdout, re.M)}
    edges = [(int(a), int(b)) for a, b in re.findall(r"^\s*(\d+) -> (\d+)", r.stdout, re.M)]
    (table,) = [i for i, lab in labels.items() if lab.startswith("table")]
    parent = {i: i for i in labels}

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for a, b in edges:
        if table not in (a, b):
            parent[root(a)] = root(b)
    chains: dict[int, list[str]] = {}
    for i, lab in labels.items():
        if i != table:
            chains.setdefault(root(i), []).append(lab)
    assert len(chains) == 3
    systems = sorted(lab.split("system: ")[1] for c in chains.values() for lab in c if lab.startswith("ingest"))
    assert systems == ["oscillating_cart", "red_apple_pendulum", "toy"]
    for c in chains.values():
        assert sorted(lab.split("\\n")[0] for lab in c if not lab.startswith("download")) == ["chart", "evaluate", "figures", "ingest", "stage1", "stage2"]


def _row_file(path: Path, clip: str, truth: str, verdict: str, budget: str = "cheap") -> str:
    """A file as ``benchmarks/diagnosis.py --clip <clip> --row <path>`` writes it (no refit: a control or a miss)."""
    row = {"clip": clip, "system": clip.split("-")[0], "truth": truth, "verdict": verdict, "ok": truth == verdict, "refit": False, "reliable": True,
           "before": {k: 0.01 for k in GAP_METRICS}, "after": {k: None for k in GAP_METRICS}, "s": 40.0}  # fmt: skip
    row |= {f"red_{k}": None for k in GAP_METRICS} | {f"red_ctrl_{k}": None for k in GAP_METRICS}
    path.write_text(json.dumps({"budget": budget, "row": row, "timing": {"stage1": 11.0, "stage2": 17.0}}))
    return str(path)


def test_the_scoring_rule_summarises_the_per_clip_rows(tmp_path):
    rows = [
        _row_file(tmp_path / "a.json", "pendulum-none-0", "none", "none"),
        _row_file(tmp_path / "b.json", "pendulum-coulomb-0", "coulomb", "coulomb"),
        _row_file(tmp_path / "c.json", "cart-drift-0", "drift", "none"),
        _row_file(tmp_path / "d.json", "cart-none-0", "none", "end_stop"),
    ]
    md, js = tmp_path / "summary.md", tmp_path / "summary.json"
    cmd = [sys.executable, "benchmarks/diagnosis.py", "--gather", *rows, "--markdown", str(md), "--json", str(js)]
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "top-1 accuracy: 0.500 (2/4)" in r.stdout and "controls flagged: 1/2" in r.stdout
    text = md.read_text()
    assert text.startswith("# Blind diagnosis suite: budget cheap, 4 clips\n")
    assert "- top-1 accuracy: 0.500 (2/4)" in text and "- controls flagged: 1/2" in text
    assert all(f"| {name} " in text for name in ("pendulum-none-0", "pendulum-coulomb-0", "cart-drift-0", "cart-none-0"))
    assert re.search(r"^\| truth\s+\|", text, re.M)  # the confusion matrix, as a markdown table
    rec = json.loads(js.read_text())
    assert rec["budget"] == "cheap" and rec["accuracy"] == 0.5 and rec["controls_flagged"] == 1
    assert [row["clip"] for row in rec["rows"]] == ["pendulum-none-0", "pendulum-coulomb-0", "cart-drift-0", "cart-none-0"]
    # rows of two budgets are not scored together
    other = _row_file(tmp_path / "e.json", "cart-none-1", "none", "none", budget="standard")
    r2 = subprocess.run([sys.executable, "benchmarks/diagnosis.py", "--gather", rows[0], other], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r2.returncode != 0 and "2 budgets" in r2.stderr


def test_an_offline_download_still_says_what_to_fetch(tmp_path):
    # the download's one-line message goes to its log and, as the rule failed, to Snakemake's stderr too
    raw, res = tmp_path / "raw", tmp_path / "res"
    cmd = ["snakemake", "-c1", f"{raw}/oscillating_cart.webm", "--config", f"raw_dir={raw}", f"results_dir={res}",
           "overrides=system.source.url=http://127.0.0.1:9/oscillatingCar.webm"]  # fmt: skip
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode != 0
    log = res / "logs" / "download" / "oscillating_cart.webm.log"
    line = log.read_text().strip().splitlines()[-1]
    assert str(raw / "oscillating_cart.webm") in line and line in r.stderr
    assert not (raw / "oscillating_cart.webm").exists()


def test_the_deformation_table_declares_the_variant_stage1_it_trains(tmp_path):
    # the job trains the deformation decoder's own Stage 1; Snakemake must know the file (clean-up, reruns)
    res = tmp_path / "res"
    r = dry_run([f"{res}/oscillating_cart/variants/deformation/stage1.pt", "--config", f"results_dir={res}", f"raw_dir={tmp_path / 'raw'}"])
    assert r.returncode == 0, r.stdout
    assert "deformation_table" in {j["rule"] for j in jobs(r.stdout)}


def test_every_stage_gets_the_paths_its_rule_declares(tmp_path):
    # a job running `python -m lagsplat <stage>` is handed every file it writes (artifacts.<name>=PATH) and every
    # file it reads (a table's inputs as 'artifacts.table_inputs=[...]'), so no stage works a declared path out again
    res, raw = tmp_path / "res", tmp_path / "raw"
    targets = [f"{res}/tables/physical.tex", f"{res}/tables/two_carts_inertia.tex", f"{res}/toy/diagnosis/report.md", f"{res}/tables/deformation.tex",
               f"{res}/tables/extrapolation.tex", f"{res}/pendulum3d/metrics.json", f"{res}/tables/toy_seeds.md",
               f"{res}/pendulum3d/figures/novel_views.png", f"{res}/tables/novel_views.csv"]  # fmt: skip
    r = dry_run([*targets, "krauss", "--config", f"results_dir={res}", f"raw_dir={raw}", "krauss_source=synthetic", "seeds=0,1"])
    assert r.returncode == 0, r.stdout
    staged = [j for j in jobs(r.stdout) if "python -m lagsplat " in j.get("shell", "")]
    assert {j["rule"] for j in staged} >= {"download", "ingest", "views", "stage1", "chart", "stage2", "evaluate", "figures", "table", "ablation_table",
                                           "stage2_variant", "evaluate_variant", "diagnose", "deformation_table", "extrapolation", "extrapolation_table",
                                           "krauss_table", "robot_figures", "seed_run", "seed_table", "render", "views_table"}  # fmt: skip
    for j in staged:
        # key=PATH, and the items of key=[PATH,PATH,...]
        handed = set(re.findall(r"=([^\s'\[\],]+)", j["shell"])) | {p for items in re.findall(r"=\[([^\]]*)\]", j["shell"]) for p in items.split(",")}
        for path in filter(None, (p.strip() for p in j.get("output", "").split(","))):
            assert path in handed or f"/diagnosis/{Path(path).name}" in path, (j["rule"], path, j["shell"])  # the diagnosis: its folder
        for path in filter(None, (p.strip() for p in j.get("input", "").split(","))):
            # only dependencies: the rollout figures a table waits for, the source files that trigger the views job
            if (j["rule"] == "table" and path.endswith("rollout.png")) or (j["rule"] == "views" and not path.endswith("clip.npz")):
                continue
            assert path in handed, (j["rule"], path, j["shell"])
    views = [j for j in staged if j["rule"] == "views"]
    assert views and all(j["output"] == f"{res}/pendulum3d/views" for j in views)  # the whole folder: views.npz, cameras.json, views.json


@pytest.mark.parametrize("profile", PROFILES)
def test_the_paper_target_plans_every_item_then_the_page(tmp_path, slurm_stubs, profile):
    # every table and figure of lagsplat.report.paper, offline (the soft robot's surrogate whatever krauss_source
    # says), each job logged, then the results page; the SLURM profile plans the same jobs and submits nothing
    env, calls = slurm_stubs
    res, raw = tmp_path / "res", tmp_path / "raw"
    r = dry_run([*profile, "paper", "--config", f"results_dir={res}", f"raw_dir={raw}"], env=env)
    assert r.returncode == 0, r.stdout
    counts = job_counts(r.stdout)
    seeds = len(yaml.safe_load((ROOT / "conf" / "config.yaml").read_text())["seed_table"]["seeds"])
    assert seeds == 5 and counts["seed_run"] == seeds * len(SEED_SYSTEMS) and counts["seed_table"] == len(SEED_SYSTEMS)
    assert {"krauss_archive", "krauss_extract"}.isdisjoint(counts) and counts["krauss_synth"] == 2
    assert counts["results_page"] == counts["paper"] == counts["render"] == counts["views_table"] == counts["krauss_table"] == 1
    planned = jobs(r.stdout)
    for j in planned:
        if j["rule"] != "paper":  # a target rule runs nothing
            assert_logged(j)
    (page,) = [j for j in planned if j["rule"] == "results_page"]
    assert {p.strip() for p in page["input"].split(",")} == {it.path for it in paper_items(res)}
    assert page["output"] == "docs/results.md, docs/results"
    assert f"--results {res} " in page["shell"]
    (table,) = [j for j in planned if j["rule"] == "krauss_table"]
    assert f"krauss_table.two_segments={KRAUSS_SURROGATE['2seg']} " in table["shell"] and table["output"].startswith(f"{res}/tables/krauss_surrogate.tex")
    called = calls.read_text().splitlines() if calls.exists() else []
    assert not [c for c in called if c.split()[0] in ("sbatch", "srun", "scancel")], called


def test_the_paper_target_prints_its_projected_wall_time_before_the_first_job(tmp_path):
    # --touch runs the onstart handler and then touches outputs instead of running any job; the workflow is a copy, so
    # that the repository's docs/results.md is left alone
    wf = tmp_path / "wf"
    wf.mkdir()
    for name in ("Snakefile", "workflow", "conf"):
        (shutil.copytree if (ROOT / name).is_dir() else shutil.copy)(ROOT / name, wf / name)
    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    cfg = ["--config", f"results_dir={tmp_path / 'res'}", f"raw_dir={tmp_path / 'raw'}"]

    def touch(target: str, *config: str) -> list[str]:
        r = subprocess.run(["snakemake", "-c2", "--touch", target, *cfg, *config], cwd=wf, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
        assert r.returncode == 0, r.stdout
        return [line for line in r.stdout.splitlines() if line.startswith("[lagsplat]")]

    lines = touch("paper")
    assert lines[0].startswith("[lagsplat] projected wall time of the paper target on 2 core(s): at least "), lines
    keys = [it.key for it in paper_items(tmp_path / "res")]
    assert [line.removeprefix("[lagsplat]").split(":")[0].strip() for line in lines[1 : 1 + len(keys)]] == keys  # per item, in order
    assert lines[-1].startswith("[lagsplat]   not in the cost model") and "extrapolation x3" in lines[-1] and "diagnose x1" in lines[-1]
    # the soft-robot projection is still printed for a run without the paper target
    robot = touch("krauss", "krauss_source=synthetic")
    assert robot and robot[0].startswith("[lagsplat] projected wall time of the soft-robot jobs on 2 core(s)"), robot

def views_input(name):
    """A 3-D system's view source files (conf/system/<name>.yaml, system.views): the views job reruns when one changes."""
    v = system_conf(name).get("views") or {}
    files = [v[k] for k in ("path", "cameras", "calibration", "checkpoint") if v.get(k)] + list(v.get("videos") or [])
    return [f.replace("${raw_dir}", RAW) for f in files]


def stage1_input(name):
    """Stage 1's inputs: the clip, and a 3-D system's cached views."""
    return {"clip": str(ART.clip).format(system=name), **({"views": str(ART.views).format(system=name)} if system_conf(name).get("views") else {})}


rule views:
    """A 3-D system's cached novel views of every frame and their cameras (lagsplat.views): the folder views/
    (views.npz, cameras.json, views.json), declared whole. Snakemake removes it before the job runs, so a rerun
    computes the views again; the stage's own cache (views.npz's key) serves runs outside Snakemake."""
    input:
        clip=str(ART.clip),
        sources=lambda w: views_input(w.system),
    output:
        views=directory(str(ART.views)),
    log:
        f"{RESULTS}/logs/{{system}}/views.log",
    threads: 1
    shell:
        cli("views", ["clip"], ["views"])


rule pendulum3d_data:
    """The synthetic 3-D test system rendered by MuJoCo (lagsplat.synth.pendulum3d): the main camera's clip,
    the extra cameras' views, the cameras and the ground truth."""
    output:
        npz=f"{RAW}/pendulum3d.npz",
        views=f"{RAW}/pendulum3d.views.npz",
        cameras=f"{RAW}/pendulum3d.cameras.json",
        truth=f"{RAW}/pendulum3d.truth.npz",
    params:
        g=lambda w: system_conf("pendulum3d")["source"]["generator"],
    log:
        f"{RESULTS}/logs/pendulum3d/data.log",
    shell:
        "MUJOCO_GL=${{MUJOCO_GL:-egl}} python -m lagsplat.synth.pendulum3d --out {RAW}/pendulum3d --size {params.g[size]} "
        "--views {params.g[views]} --duration-s {params.g[duration_s]} --fps {params.g[fps]} --seed {params.g[seed]} > {log} 2>&1"


ruleorder: pendulum3d_data > download

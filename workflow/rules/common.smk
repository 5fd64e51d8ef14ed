# Shared helpers: the effective config, the scene plan, real clips, and input functions. No rules here.
# Paths come from lightcrafter.layout.Layout (one builder per product); dataset variants and held-out
# benchmarks from the registries in lightcrafter.datasets; Phi's backends from lightcrafter.recon.BACKENDS.
# Settings and plans reach scripts through files the workflow writes (params_file), never on a command line.
import functools
import hashlib
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, workflow.basedir)

from lightcrafter import datasets as ds
from lightcrafter.codeversion import code_fingerprint
from lightcrafter.config import effective_config, raw_config, validate
from lightcrafter.ingest import real_clips
from lightcrafter.layout import Layout
from lightcrafter.mit_multi_illum import plan as mit_plan
from lightcrafter.scenes import ConfigError, plan_scene, renders_recon_split, scene_ids

# The effective config (python -m lightcrafter.config prints the same): the --configfile files (their
# `extends` chains resolved; none given: config/config.yaml), then --config, validated and checked on disk.
try:
    _EFFECTIVE = effective_config(
        workflow.overwrite_configfiles, dict(workflow.config_settings.config)
    )
except ConfigError as exc:
    sys.exit(f"ConfigError: {exc}")
config.clear()
config.update(_EFFECTIVE)

OUT = config["output_dir"]
L = Layout(OUT)
SEED = config["seed"]
SCENE_IDS = scene_ids(config["scenes"])
_PLANS = {sid: plan_scene(config["scenes"], SEED, i) for i, sid in enumerate(SCENE_IDS)}
# Real clips: ids fixed by config (video, chunk index; DL3DV scene folders), so the DAG is known before any
# video is read.
REAL = real_clips(config["real"], seed=SEED)
# MIT Multi-Illumination benchmark (config mit.root; empty by default): one-frame clips and pairs.
MIT = mit_plan(config["mit"])


def _is_dry_run(argv) -> bool:
    """-n / --dry-run on Snakemake's command line (also in a flag group such as -np)."""
    return any(
        a in ("--dry-run", "--dryrun")
        or (a[:1] == "-" and a[1:2] != "-" and a[1:].isalpha() and "n" in a)
        for a in argv[1:]
    )


# A dry run prints the expected files and bytes per product (lightcrafter.storage), to stderr.
if workflow.is_main_process and _is_dry_run(sys.argv):
    from lightcrafter import storage as _storage

    _TABLE = _storage.table(_storage.project(config))
    print(
        f"Expected storage of this run (python -m lightcrafter.storage --measured <results> applies measured "
        f"compression):\n{_TABLE}",
        file=sys.stderr,
    )
for _cid, _c in MIT["clips"].items():
    REAL[_cid] = {
        "video": _c["image"],
        "split": "mit",
        "chunk": 0,
        "start_frame": 0,
        "frame_step": 1,
        "num_frames": 1,
        "fov_x_deg": float(config["mit"]["fov_x_deg"]),
        "scene_static": True,
        "camera_static": True,
    }
# Dataset variants trained by the default target (each one of lightcrafter.datasets.VARIANTS).
DATASET_VARIANTS = list(config["datasets"]["variants"])
BENCHMARKS = (
    ["synthetic"]
    + (["real"] if any(c["split"] == "test" for c in REAL.values()) else [])
    + (["mit"] if MIT["pairs"] else [])
)

CURATION_JOBS = int(config["assets"]["curation_jobs"])
GPU_RENDER_DEVICES = ("cuda", "optix")


def blender_resources():
    """Extra resources of the Blender (Cycles) rules: one GPU on the gpu partition when render.device
    asks for one (cuda, optix); none for cpu and auto (auto on a CPU node renders on the CPU). The SLURM
    profile leaves these rules' partition to this (profiles/slurm/config.yaml)."""
    if config["render"]["device"] in GPU_RENDER_DEVICES:
        return {"slurm_partition": "gpu", "gpu": 1}
    return {}


PARAMS_DIR = Path(".snakemake") / "lightcrafter-params"
_PARAMS_WRITTEN = {}


def params_file(obj):
    """Settings or a plan for a script as a content-addressed JSON file: '@<path>' (scripts read it with
    scripts/_cli.json_arg). The path changes exactly when the content does, so Snakemake's params trigger
    still reruns a job whose settings changed, and no command line carries the data."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"))
    if text not in _PARAMS_WRITTEN:
        digest = hashlib.sha256(text.encode()).hexdigest()[:24]
        path = PARAMS_DIR / f"{digest}.json"
        if not path.is_file():
            PARAMS_DIR.mkdir(parents=True, exist_ok=True)
            tmp = PARAMS_DIR / f".{digest}.{os.getpid()}.tmp"
            tmp.write_text(text)
            os.replace(tmp, path)
        _PARAMS_WRITTEN[text] = f"@{path}"
    return _PARAMS_WRITTEN[text]


wildcard_constraints:
    scene=r"s\d{4}",
    traj=r"t\d+",
    light=r"L\d+",
    clip=r"[A-Za-z0-9][A-Za-z0-9_]*",
    pair=r"mit_[A-Za-z0-9_]+_to_d\d+",
    kind="light|material|object",
    variant="|".join(ds.VARIANTS),
    bench="|".join(ds.BENCHMARKS),


def scene_plan(scene_id):
    """Split and trajectories of a scene (see lightcrafter.scenes.plan_scene)."""
    return _PLANS[scene_id]


def scenes_in_split(*splits):
    return [sid for sid in SCENE_IDS if _PLANS[sid]["split"] in splits]


def trajectory_plan(scene_id, traj_id):
    for t in _PLANS[scene_id]["trajectories"]:
        if t["id"] == traj_id:
            return t
    raise ValueError(f"scene {scene_id} has no trajectory {traj_id}")


def script_path(name):
    """Absolute path of an entry point in scripts/ (rules call them with the env's python)."""
    return str(Path(workflow.basedir) / "scripts" / name)


@functools.lru_cache(maxsize=None)  # one fingerprint per script and workflow parse
def _code(name):
    return code_fingerprint(script_path(name), workflow.basedir)


def script_params(name):
    """A rule's params for its entry point: `script` (script_path) and `code`, the fingerprint of the script
    and the library code it imports (lightcrafter.codeversion), so that editing either reruns the rule's jobs
    (Snakemake's params trigger; its code trigger does not see shell commands)."""
    return {
        "script": script_path(name),
        "code": _code(name),
    }


# ----------------------------------------------------------------------------- ground truth
def rendered_scenes():
    """The scenes this run renders: the recon split only feeds the estimator's training, so it is left out
    when Phi uses weights from elsewhere (recon.estimator.weights: shipped or a file) or the paper stack.
    """
    trains = renders_recon_split(config)
    return [sid for sid in SCENE_IDS if trains or _PLANS[sid]["split"] != "recon"]


def gt_buffer_manifests(scene_ids=None):
    """Every rendered trajectory's ground-truth clip manifest (lighting-independent: one per trajectory)."""
    return [
        L.gt_clip_manifest(sid, t["id"])
        for sid in (scene_ids or rendered_scenes())
        for t in _PLANS[sid]["trajectories"]
    ]


def gt_rgb_manifests(scene_ids=None):
    """Every rendered (trajectory, lighting) that some pair uses; unused lightings are left out."""
    return [
        f"{L.gt_rgb(sid, t['id'], light)}.json"
        for sid in (scene_ids or rendered_scenes())
        for t in _PLANS[sid]["trajectories"]
        for light in t["render_lights"]
    ]


def parent_dir(wildcards, output):
    """Folder of the rule's first output (files written beside their manifest)."""
    return str(Path(output[0]).parent)


def curated_dir(wildcards, output):
    """Curated GLBs live in curated/ beside the manifest."""
    return str(Path(output[0]).parent / "curated")


def trajectory_dir(wildcards, output):
    """The trajectory folder from any of its outputs (buffers.json or rgb/{light}.json)."""
    out = Path(output[0])
    return str(out.parent.parent if out.parent.name == "rgb" else out.parent)


def curation_inputs(wildcards):
    if config["assets"]["source"] == "procedural":
        return f"{OUT}/assets/raw/generated.json"
    return []


def curation_source_dir():
    if config["assets"]["source"] == "procedural":
        return f"{OUT}/assets/raw"
    return config["assets"]["dir"]


def gt_root_of_inputs(wildcards, input):
    """results/gt from results/gt/{scene}/{traj}/buffers.json inputs."""
    return str(Path(input.buffers[0]).parents[2])


def manifest_stem(wildcards, output):
    """Frames folder beside a manifest: results/x/{light}.json -> results/x/{light}."""
    return str(Path(output[0]).with_suffix(""))


# ----------------------------------------------------------------------------- reconstruction
PAPER_STACK = config["recon"]["backend"] == "paper_stack"


def recon_settings():
    """The backend's settings: lightcrafter.recon.default.DefaultSettings fields, or the paper stack's
    commands and options (lightcrafter.recon.paper_stack), from config recon."""
    r = config["recon"]
    if PAPER_STACK:
        return r["paper_stack"]
    from lightcrafter.recon.default import config_settings

    return config_settings(config)


def estimator_weights():
    """The weights file of config recon.estimator.weights (train: this run's train_gbuffer_estimator)."""
    from lightcrafter.recon.weights import weights_path

    return str(weights_path(config["recon"]["estimator"]["weights"], L.estimator()))


def estimator_input(wildcards):
    """The G-buffer estimator, needed by the default backend only."""
    return [] if PAPER_STACK else estimator_weights()


def estimator_arg(wildcards, input):
    return f"--estimator {input.estimator}" if input.estimator else ""


def recon_backend_args():
    """Command-line arguments selecting the backend of Phi (lightcrafter.recon.BACKENDS)."""
    return f"--backend {config['recon']['backend']}"


def skip_failed_flag():
    return "--skip-failed" if config["recon"]["skip_failed"] else ""


def recon_clip_id(wildcards):
    return f"{wildcards.scene}_{wildcards.traj}"


def source_video(wildcards):
    """The source-light Cycles video of a trajectory: what Phi sees."""
    t = trajectory_plan(wildcards.scene, wildcards.traj)
    return f"{L.gt_rgb(wildcards.scene, wildcards.traj, t['source_light'])}.json"


def scene_static_flag(wildcards):
    """Video metadata given to Phi: whether objects move (the motion config of the trajectory)."""
    return int(trajectory_plan(wildcards.scene, wildcards.traj)["scene_static"])


def estimator_training_inputs(wildcards):
    """Ground-truth clips of the recon split (never train or test scenes) and their videos, paired: clip k is
    the buffers of video k, one per lighting the trajectory is rendered under (scenes.recon_lightings; the clip
    repeats)."""
    pairs = [
        (L.gt_clip_manifest(sid, t["id"]), f"{L.gt_rgb(sid, t['id'], light)}.json")
        for sid in scenes_in_split("recon")
        for t in _PLANS[sid]["trajectories"]
        for light in t["render_lights"]
    ]
    return {"clips": [c for c, _ in pairs], "videos": [v for _, v in pairs]}


def inputs_file(*names):
    """A params function: the named input lists of a rule as one file (lists of thousands of paths)."""
    return lambda wildcards, input: params_file({n: list(input[n]) for n in names})


# ----------------------------------------------------------------------------- one R (Mitsuba proxy renderer)
def proxy_settings():
    """R's settings for every job that renders with it (config proxy), through one file (scripts build
    RenderSettings from it with lightcrafter.proxy.render_settings)."""
    return params_file(config["proxy"])


# ----------------------------------------------------------------------------- real videos
def real_clip(wildcards):
    return REAL[wildcards.clip]


def real_clip_file(wildcards):
    return params_file(REAL[wildcards.clip])


# ----------------------------------------------------------------------------- datasets, refiner
def refiner_scene_plans(*splits):
    """{scene_id: scene_plan} of the scenes that give refiner pairs (split train or test)."""
    return {sid: _PLANS[sid] for sid in scenes_in_split(*(splits or ("train", "test")))}


def variant_specs(variant):
    """The training set of a variant: only its own pairs (train split, the kinds it uses), so adding
    a test clip changes no training set."""
    return ds.variant_specs(variant, L, refiner_scene_plans("train"), REAL)


def benchmark_specs(bench):
    return ds.benchmark_specs(bench, L, refiner_scene_plans("test"), REAL, MIT["pairs"])


def variant_inputs(wildcards):
    return ds.spec_inputs(variant_specs(wildcards.variant))


def benchmark_inputs(wildcards):
    return ds.spec_inputs(benchmark_specs(wildcards.bench))


def variant_specs_file(wildcards):
    return params_file(variant_specs(wildcards.variant))


def benchmark_specs_file(wildcards):
    return params_file(benchmark_specs(wildcards.bench))


def plans_file(wildcards):
    return params_file(refiner_scene_plans())


def real_num_frames(wildcards):
    return REAL[wildcards.clip].get("num_frames", config["scenes"]["num_frames"])


def mit_pair(wildcards):
    return MIT["pairs"][wildcards.pair]


def refiner_model_config():
    """The refiner config the scripts get (the workflow-only 'resources' key removed). A checkpoint's
    empty-prompt embedding is read from the file rule encode_empty_prompt writes, unless the config
    names one (model.empty_prompt_cache)."""
    cfg = {k: v for k, v in config["refiner"].items() if k != "resources"}
    if cfg["model"]["kind"] == "paper" and not cfg["model"]["empty_prompt_cache"]:
        cfg = dict(cfg, model=dict(cfg["model"], empty_prompt_cache=L.empty_prompt()))
    return cfg


def refiner_prompt_input():
    """The empty-prompt embedding the refiner rules need (paper model without a configured file), or []."""
    m = config["refiner"]["model"]
    return (
        [L.empty_prompt()]
        if m["kind"] == "paper" and not m["empty_prompt_cache"]
        else []
    )


def refiner_launcher():
    """How train_refiner starts: python, or accelerate launch with one process per GPU (resources.gpus)."""
    n = refiner_resource("gpus")
    if n == 1:
        return "python"
    return f"accelerate launch --multi_gpu --num_machines 1 --num_processes {n} --mixed_precision no"


def refiner_config_file(wildcards):
    """The refiner config of a variant's training. The baselines (one-step regressor, affine colour) are
    Table 1 methods: trained with the first variant of datasets.variants only."""
    cfg = refiner_model_config()
    if wildcards.variant != DATASET_VARIANTS[0]:
        cfg = dict(cfg, baselines={"regressor_steps": 0, "affine_colour": False})
    return params_file(cfg)


def refiner_infer_file(wildcards):
    """Inference overrides applied on top of the config stored with the trained model."""
    return params_file(
        {"infer": config["refiner"]["infer"], "device": config["refiner"]["device"]}
    )


def refiner_resource(key):
    return config["refiner"]["resources"][key]


def variant_priority(wildcards):
    """The variant the long-form check and the edits refine with builds and trains first among variants whose
    pairs are ready: the most work waits on it (the default run trained it last, alone on one of two cores for its
    final 2.5 minutes)."""
    users = [
        config[k]["variant"] for k in ("longform", "edits") if config[k]["enabled"]
    ]
    return 5 if wildcards.variant in users else 0


def refiner_threads():
    return refiner_resource("threads")


def refiner_outputs():
    """Evaluation outputs of every configured variant on every benchmark."""
    return [L.eval_metrics(v, b) for v in DATASET_VARIANTS for b in BENCHMARKS]


def report_inputs():
    """What the run report summarises."""
    return [
        L.summary("ground_truth"),
        L.summary("reconstruction"),
        *refiner_outputs(),
        *extra_outputs(),
    ]


def paper_config_file(wildcards):
    """The paper's effective config (validated, not checked on disk), whose cost the report projects:
    read only when the report job is planned, not at every parse of the workflow."""
    paper = Path(workflow.basedir) / "config" / "paper.yaml"
    return params_file(validate(raw_config([paper]), "config/paper.yaml"))


def results_root(wildcards, output):
    """results/ from results/report/index.html."""
    return str(Path(output[0]).parents[1])


def real_recon_settings(wildcards):
    """Phi's settings for a real clip: the video's own field-of-view prior and camera flag."""
    c = REAL[wildcards.clip]
    if PAPER_STACK:
        return params_file(recon_settings())
    return params_file(
        dict(
            recon_settings(),
            fov_x_deg=c["fov_x_deg"],
            camera="static" if c["camera_static"] else "auto",
        )
    )


def real_scene_static(wildcards):
    return int(REAL[wildcards.clip]["scene_static"])


def clip_dir_of_input(wildcards, input):
    """A clip folder from the rule's 'clip' manifest input."""
    return str(Path(input.clip).parent)


def manifest_stem_of_input(wildcards, input):
    """Frames folder beside the rule's 'video' manifest input."""
    return str(Path(input.video).with_suffix(""))


def synthetic_recon_inputs(wildcards):
    """Phi clips, aligned clips and ground truth of every train/test trajectory, and real clips."""
    trajs = [
        (s, t["id"])
        for s in scenes_in_split("train", "test")
        for t in _PLANS[s]["trajectories"]
    ]
    return {
        "est": [L.recon_clip_manifest("synthetic", f"{s}_{t}") for s, t in trajs],
        "aligned": [L.aligned_clip_manifest(s, t) for s, t in trajs],
        "gt": [L.gt_clip_manifest(s, t) for s, t in trajs],
        "real": [L.recon_clip_manifest("real", c) for c in REAL],
    }


# ----------------------------------------------------------------------------- long form, edits
def _first_test_clip():
    """(scene, trajectory, target light) of the first test scene's first trajectory with a moving camera."""
    for sid in scenes_in_split("test"):
        for t in _PLANS[sid]["trajectories"]:
            if not t["camera_static"] and t["target_lights"]:
                return sid, t["id"], t["target_lights"][0]
    return None, None, None


def _longform_settings():
    lf = config["longform"]
    scene, _, _ = _first_test_clip()
    scfg = dict(
        config["scenes"],
        num_frames=int(lf["num_frames"]),
        trajectories_per_scene=1,
        motions=[lf["motion"]],
    )
    plan = plan_scene(scfg, SEED, int(scene[1:])) if scene else None
    light = plan["trajectories"][0]["target_lights"][0] if plan else None
    return {
        "scene": scene,
        "light": light,
        "variant": lf["variant"],
        "config": {
            "seed": SEED,
            "scenes": scfg,
            "render": dict(
                config["render"], spp=int(lf["spp"] or config["render"]["spp"])
            ),
        },
    }


LONGFORM = _longform_settings()
_E = _first_test_clip()
EDIT = {
    "scene": _E[0],
    "traj": _E[1],
    "light": _E[2],
    "variant": config["edits"]["variant"],
}
EDIT_KINDS = ["light", "material", "object"]


def edit_settings(wildcards):
    return params_file(config["edits"][wildcards.kind])


def edit_render_clip(wildcards):
    """Light insertion renders the reconstructed clip itself; material and object edits their edited clip."""
    if wildcards.kind == "light":
        return str(Path(L.aligned_clip_manifest(EDIT["scene"], EDIT["traj"])).parent)
    return str(Path(L.edit_clip_manifest(wildcards.kind)).parent)


def extra_outputs():
    """Long-form check and scene edits, when a test scene exists and enabled in config."""
    if EDIT["scene"] is None:
        return []
    out = []
    if config["longform"]["enabled"]:
        out.append(L.longform_metrics())
    if config["edits"]["enabled"]:
        out += [L.edit_refined(k) + ".json" for k in EDIT_KINDS]
    return out


def evaluation_args(wildcards):
    """Local weights of LPIPS and CLIP and the external methods' folder (config evaluation), if set."""
    e = config["evaluation"]
    args = []
    for key, flag in (
        ("lpips_weights", "--lpips-weights"),
        ("clip_weights", "--clip-weights"),
    ):
        if e[key]:
            args += [flag, e[key]]
    if e["external_dir"]:
        args += ["--external-dir", str(Path(e["external_dir"]) / wildcards.bench)]
    return " ".join(args)


# ----------------------------------------------------------------------------- relight (relight.smk)
def relight_name():
    r = config["relight"]
    if not r["video"]:
        raise ValueError(
            "config relight.video is not set: snakemake relight --config "
            "relight='{video: clip.mp4, hdri: sky.exr}' (config/README.md, section relight)"
        )
    if r["name"]:
        return r["name"]
    from lightcrafter.ingest import clip_stem

    return clip_stem(r["video"])


def relight_dir(*parts):
    return str(Path(config["output_dir"], "relight", relight_name(), *parts))


@functools.lru_cache(maxsize=None)
def relight_clip():
    """The ingest_video clip description of the relight video (every frame from start_frame, capped).
    Cached: counting the frames of a video file decodes it, once per workflow build."""
    r = config["relight"]
    n = r["num_frames"]
    if n is None:
        from lightcrafter.ingest import read_source, resolve_source

        total = read_source(resolve_source(r["video"], "relight.video"), [])[2]
        n = max(
            1,
            min(
                r["max_frames"],
                (total - r["start_frame"] + r["frame_step"] - 1) // r["frame_step"],
            ),
        )
    return {
        "video": r["video"],
        "chunk": 0,
        "start_frame": r["start_frame"],
        "frame_step": r["frame_step"],
        "split": "test",
        "num_frames": n,
    }


def relight_model():
    return config["relight"]["model"] or L.refiner_model(config["relight"]["variant"])


def relight_estimator(wildcards):
    return (
        [] if PAPER_STACK else (config["relight"]["estimator"] or estimator_weights())
    )

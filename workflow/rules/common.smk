# Shared helpers: config validation, the scene plan, real clips, and input functions. No rules here.
# Paths come from lightcrafter.layout.Layout (one builder per product); dataset variants from the
# registry lightcrafter.datasets.VARIANTS.
import json
import sys
from pathlib import Path

sys.path.insert(0, workflow.basedir)

from lightcrafter import datasets as ds
from lightcrafter.config import check_config
from lightcrafter.ingest import real_clips
from lightcrafter.layout import Layout
from lightcrafter.mit_multi_illum import plan as mit_plan
from lightcrafter.scenes import ConfigError, plan_scene, scene_ids

try:
    check_config(config, workflow.source_path("../schemas/config.schema.yaml"))
except ConfigError as exc:
    sys.exit(f"ConfigError: {exc}")

OUT = config["output_dir"]
L = Layout(OUT)
SEED = config["seed"]
SCENE_IDS = scene_ids(config["scenes"])
_PLANS = {sid: plan_scene(config["scenes"], SEED, i) for i, sid in enumerate(SCENE_IDS)}
# Real clips: ids fixed by config (video, chunk index), so the DAG is known before any video is read.
REAL = real_clips(config.get("real", {}))
# MIT Multi-Illumination benchmark (config mit.root; empty by default): one-frame clips and pairs.
MIT = mit_plan(config.get("mit"))
for _cid, _c in MIT["clips"].items():
    REAL[_cid] = {
        "video": _c["image"],
        "split": "mit",
        "chunk": 0,
        "start_frame": 0,
        "frame_step": 1,
        "num_frames": 1,
        "fov_x_deg": float(config["mit"].get("fov_x_deg", 60.0)),
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


def as_json(obj):
    """Compact JSON for passing config sections on a command line (quote with :q)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


# ----------------------------------------------------------------------------- ground truth
def gt_buffer_manifests(scene_ids=None):
    """Every trajectory's ground-truth clip manifest (lighting-independent: one per trajectory)."""
    return [
        L.gt_clip_manifest(sid, t["id"])
        for sid in (scene_ids or SCENE_IDS)
        for t in _PLANS[sid]["trajectories"]
    ]


def gt_rgb_manifests(scene_ids=None):
    """Every (trajectory, lighting) that some pair uses; unused lightings are left out."""
    return [
        f"{L.gt_rgb(sid, t['id'], light)}.json"
        for sid in (scene_ids or SCENE_IDS)
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
def recon_settings():
    """The backend's settings: lightcrafter.recon.default.DefaultSettings, or the paper stack's
    commands and options (lightcrafter.recon.paper_stack), from config."""
    r = config["recon"]
    if r.get("backend", "default") == "paper_stack":
        return dict(r.get("paper_stack", {}))
    return {
        "fov_x_deg": r.get("fov_x_deg") or config["scenes"]["fov_x_deg"],
        "normals": r.get("normals", "predicted"),
        "depth_fit": r.get("depth_fit", "scale"),
        "sfm": r.get("sfm", {}),
    }


def estimator_input(wildcards):
    """The G-buffer estimator, needed by the default backend only."""
    return (
        L.estimator() if config["recon"].get("backend", "default") == "default" else []
    )


def estimator_arg(wildcards, input):
    return f"--estimator {input.estimator}" if input.estimator else ""


def recon_backend_args():
    """Command-line arguments selecting the backend of Phi (and its settings)."""
    backend = config["recon"].get("backend", "default")
    if backend == "paper_stack":
        return f"--backend paper_stack"
    return "--backend default"


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
    """Ground-truth clips and source videos of the recon split (never train or test scenes)."""
    recon = scenes_in_split("recon")
    return {
        "clips": gt_buffer_manifests(recon) if recon else [],
        "videos": [
            f"{L.gt_rgb(sid, t['id'], t['source_light'])}.json"
            for sid in recon
            for t in _PLANS[sid]["trajectories"]
        ],
    }


# ----------------------------------------------------------------------------- real videos
def real_clip(wildcards):
    return REAL[wildcards.clip]


def real_clip_json(wildcards):
    return as_json(REAL[wildcards.clip])


# ----------------------------------------------------------------------------- datasets, refiner
def refiner_scene_plans():
    """{scene_id: scene_plan} of the scenes that give refiner pairs (split train or test)."""
    return {sid: _PLANS[sid] for sid in scenes_in_split("train", "test")}


def plans_json(wildcards):
    return as_json(refiner_scene_plans())


def real_json(wildcards):
    return as_json(REAL)


def variant_inputs(wildcards):
    specs = ds.variant_specs(wildcards.variant, L, refiner_scene_plans(), REAL)
    return ds.spec_inputs(specs)


def benchmark_inputs(wildcards):
    specs = ds.benchmark_specs(
        wildcards.bench, L, refiner_scene_plans(), REAL, MIT["pairs"]
    )
    return ds.spec_inputs(specs)


def mit_json(wildcards):
    return as_json(MIT["pairs"])


def real_num_frames(wildcards):
    return REAL[wildcards.clip].get("num_frames", config["scenes"]["num_frames"])


def mit_pair(wildcards):
    return MIT["pairs"][wildcards.pair]


def refiner_model_config():
    """The refiner config dict passed to the scripts (the workflow-only 'resources' key removed)."""
    return {k: v for k, v in config.get("refiner", {}).items() if k != "resources"}


def refiner_config_json(wildcards):
    """The refiner config of a variant's training. The baselines (one-step regressor, affine colour) are
    Table 1 methods: trained with the first variant of datasets.variants only."""
    cfg = refiner_model_config()
    if wildcards.variant != DATASET_VARIANTS[0]:
        cfg = dict(cfg, baselines={"regressor_steps": 0, "affine_colour": False})
    return as_json(cfg)


def refiner_infer_json(wildcards):
    """Inference overrides applied on top of the config stored with the trained model."""
    return as_json({"infer": refiner_model_config().get("infer", {})})


def refiner_resource(key, default):
    return config.get("refiner", {}).get("resources", {}).get(key, default)


def refiner_threads():
    return refiner_resource("threads", 2)


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


def results_root(wildcards, output):
    """results/ from results/report/index.html."""
    return str(Path(output[0]).parents[1])


def real_recon_settings(wildcards):
    """Phi's settings for a real clip: the video's own field-of-view prior."""
    c = REAL[wildcards.clip]
    if config["recon"].get("backend", "default") == "paper_stack":
        return as_json(recon_settings())
    return as_json(
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
    lf = config.get("longform", {})
    scene, _, _ = _first_test_clip()
    scfg = dict(
        config["scenes"],
        num_frames=int(lf.get("num_frames", 201)),
        trajectories_per_scene=1,
        motions=[lf.get("motion", "orbit_static")],
        splits=config["scenes"]["splits"],
    )
    plan = plan_scene(scfg, SEED, int(scene[1:])) if scene else None
    light = plan["trajectories"][0]["target_lights"][0] if plan else None
    return {
        "scene": scene,
        "light": light,
        "variant": lf.get("variant", "full"),
        "config": {
            "seed": SEED,
            "scenes": scfg,
            "render": dict(config["render"], spp=int(lf.get("spp", 4))),
        },
    }


LONGFORM = _longform_settings()
_E = _first_test_clip()
EDIT = {
    "scene": _E[0],
    "traj": _E[1],
    "light": _E[2],
    "variant": config.get("edits", {}).get("variant", "full"),
}
EDIT_KINDS = ["light", "material", "object"]


def edit_settings(wildcards):
    return as_json(config.get("edits", {}).get(wildcards.kind, {}))


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
    if config.get("longform", {}).get("enabled", True):
        out.append(L.longform_metrics())
    if config.get("edits", {}).get("enabled", True):
        out += [L.edit_refined(k) + ".json" for k in EDIT_KINDS]
    return out


def evaluation_args(wildcards):
    """Local weights of LPIPS and CLIP and the external methods' folder (config evaluation), if set."""
    e = config.get("evaluation", {})
    args = []
    for key, flag in (
        ("lpips_weights", "--lpips-weights"),
        ("clip_weights", "--clip-weights"),
    ):
        if e.get(key):
            args += [flag, e[key]]
    if e.get("external_dir"):
        args += ["--external-dir", str(Path(e["external_dir"]) / wildcards.bench)]
    return " ".join(args)

# Shared helpers: config validation, the scene plan, and path builders. No rules here.
import json
import sys
from pathlib import Path

sys.path.insert(0, workflow.basedir)

from lightcrafter.config import check_config
from lightcrafter.scenes import ConfigError, plan_scene, scene_ids

try:
    check_config(config, workflow.source_path("../schemas/config.schema.yaml"))
except ConfigError as exc:
    sys.exit(f"ConfigError: {exc}")

OUT = config["output_dir"]
SEED = config["seed"]
SCENE_IDS = scene_ids(config["scenes"])
_PLANS = {sid: plan_scene(config["scenes"], SEED, i) for i, sid in enumerate(SCENE_IDS)}
# Pair-manifest variants that have a dataset rule (dataset.smk). full, no_real and no_synthetic
# join when the reconstruction stack and real pseudo-pairs exist; until then they cannot be
# requested (the {variant} wildcard only matches these).
DATASET_VARIANTS = ["clean_buffers"]


wildcard_constraints:
    scene=r"s\d{4}",
    traj=r"t\d+",
    light=r"L\d+",
    variant="|".join(DATASET_VARIANTS),


def scene_plan(scene_id):
    """Split and trajectories of a scene (see lightcrafter.scenes.plan_scene)."""
    return _PLANS[scene_id]


def scenes_in_split(split):
    return [sid for sid in SCENE_IDS if _PLANS[sid]["split"] == split]


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


def gt_buffer_manifests(scene_ids=None):
    """Every trajectory's buffer manifest (lighting-independent: one per trajectory)."""
    return [
        f"{OUT}/gt/{sid}/{t['id']}/buffers.json"
        for sid in (scene_ids or SCENE_IDS)
        for t in _PLANS[sid]["trajectories"]
    ]


def gt_rgb_manifests(scene_ids=None):
    """Every (trajectory, lighting) that some pair uses; unused lightings are left out."""
    return [
        f"{OUT}/gt/{sid}/{t['id']}/rgb/{light}.json"
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
    """results/gt/{scene}/{traj} from any of its outputs (buffers.json or rgb/{light}.json)."""
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


def report_inputs():
    """What the run report summarises: ground-truth counts and every variant's evaluation."""
    return [f"{OUT}/summary/ground_truth.json", *refiner_outputs()]


def results_root(wildcards, output):
    """results/ from results/report/index.html."""
    return str(Path(output[0]).parents[1])


# ----------------------------------------------------------------------------- datasets, refiner
def refiner_scene_plans():
    """{scene_id: scene_plan} of the scenes that give refiner pairs (split train or test)."""
    return {
        sid: scene_plan(sid)
        for sid in SCENE_IDS
        if scene_plan(sid)["split"] in ("train", "test")
    }


def clean_buffers_inputs(wildcards):
    """Proxy-from-GT-buffers manifests and Cycles target manifests of every clean_buffers pair."""
    files = []
    for sid, plan in refiner_scene_plans().items():
        for traj in plan["trajectories"]:
            for light in traj["target_lights"]:
                files.append(f"{OUT}/proxy_gt/{sid}/{traj['id']}/{light}.json")
                files.append(f"{OUT}/gt/{sid}/{traj['id']}/rgb/{light}.json")
    return files


def refiner_plans_json(wildcards):
    return as_json(refiner_scene_plans())


def refiner_model_config():
    """The refiner config dict passed to the scripts (the workflow-only 'resources' key removed)."""
    return {k: v for k, v in config.get("refiner", {}).items() if k != "resources"}


def refiner_config_json(wildcards):
    return as_json(refiner_model_config())


def refiner_infer_json(wildcards):
    """Inference overrides applied on top of the config stored with the trained model."""
    return as_json({"infer": refiner_model_config().get("infer", {})})


def refiner_resource(key, default):
    return config.get("refiner", {}).get("resources", {}).get(key, default)


def refiner_threads():
    return refiner_resource("threads", 2)


def refiner_pairs(wildcards):
    return f"{OUT}/datasets/{wildcards.variant}/pairs.jsonl"


def refiner_outputs():
    """Evaluation outputs of every dataset variant that exists."""
    return [f"{OUT}/eval/{v}/metrics.json" for v in DATASET_VARIANTS]


def manifest_stem(wildcards, output):
    """Frames folder beside a manifest: results/x/{light}.json -> results/x/{light}."""
    return str(Path(output[0]).with_suffix(""))

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


wildcard_constraints:
    scene=r"s\d{4}",
    traj=r"t\d+",
    light=r"L\d+",


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
    """What the run report summarises (grows as stages are added)."""
    return [f"{OUT}/summary/ground_truth.json"]


def results_root(wildcards, output):
    """results/ from results/report/index.html."""
    return str(Path(output[0]).parents[1])

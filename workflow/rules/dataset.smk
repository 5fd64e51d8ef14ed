# Pair manifests results/datasets/{variant}/pairs.jsonl (contract: docs/architecture.md).
# Only variants whose data stages exist have a rule here; each appends itself to
# DATASET_VARIANTS, which constrains the refiner's {variant} wildcard (include this file
# before refiner.smk). full / no_real / no_synthetic plug in as rules when their stages exist.

DATASET_VARIANTS = ["clean_buffers"]


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


rule dataset_clean_buffers:
    input:
        clean_buffers_inputs,
    output:
        pairs=f"{OUT}/datasets/clean_buffers/pairs.jsonl",
    log:
        "logs/dataset/clean_buffers.log",
    benchmark:
        "logs/benchmark/dataset/clean_buffers.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        script=script_path("build_dataset.py"),
        plans=refiner_plans_json,
    shell:
        "python {params.script} --variant clean_buffers "
        "--plans-json {params.plans:q} --output {output.pairs} > {log} 2>&1"

# LightCrafter: synthetic scenes -> ground truth -> Phi -> proxies -> pairs -> refiner -> evaluation.
# Configuration: --configfile config/paper.yaml (the paper's run) or none (config/config.yaml, the laptop
# rehearsal); the typed models in lightcrafter/config/models.py define every key (config/README.md),
# and workflow/rules/common.smk validates and checks the config before any job starts.
from pathlib import Path

from snakemake.utils import min_version

min_version("9.0")


include: "workflow/rules/common.smk"
include: "workflow/rules/assets.smk"
include: "workflow/rules/scenes.smk"
include: "workflow/rules/render.smk"
include: "workflow/rules/reconstruct.smk"
include: "workflow/rules/ingest.smk"
include: "workflow/rules/proxy.smk"
include: "workflow/rules/dataset.smk"
include: "workflow/rules/refiner.smk"
include: "workflow/rules/longform.smk"
include: "workflow/rules/edit.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/relight.smk"


rule ground_truth:
    input:
        gt_buffer_manifests(),
        gt_rgb_manifests(),
        L.summary("ground_truth"),


rule scene_specs:
    input:
        [L.scene_spec(s) for s in SCENE_IDS],


rule pairs:
    input:
        [L.pairs(v) for v in DATASET_VARIANTS],
        [L.benchmark_pairs(b) for b in BENCHMARKS],


rule ablations:
    input:
        [L.eval_metrics(v, b) for v in ds.VARIANTS for b in BENCHMARKS],


rule longform_check:
    input:
        L.longform_metrics(),


rule edits:
    input:
        [L.edit_refined(k) + ".json" for k in EDIT_KINDS],


rule all:
    default_target: True
    input:
        rules.ground_truth.input,
        L.summary("reconstruction"),
        refiner_outputs(),
        extra_outputs(),
        L.report_index(),

# LightCrafter: synthetic scenes -> ground truth -> proxies -> pairs -> refiner -> evaluation.
# Configuration: config/config.yaml (laptop default) or config/paper.yaml (paper scale);
# every key is documented in config/README.md and validated against workflow/schemas/.
from pathlib import Path

from snakemake.utils import min_version

min_version("9.0")


# The default config sits beside this file, whatever the working directory (--directory).
configfile: str(Path(workflow.basedir) / "config" / "config.yaml")


include: "workflow/rules/common.smk"
include: "workflow/rules/assets.smk"
include: "workflow/rules/scenes.smk"
include: "workflow/rules/render.smk"
include: "workflow/rules/proxy.smk"
include: "workflow/rules/dataset.smk"
include: "workflow/rules/refiner.smk"
include: "workflow/rules/report.smk"


rule ground_truth:
    input:
        gt_buffer_manifests(),
        gt_rgb_manifests(),
        f"{OUT}/summary/ground_truth.json",


rule scene_specs:
    input:
        expand(f"{OUT}/scenes/{{scene}}/scene.json", scene=SCENE_IDS),


rule all:
    default_target: True
    input:
        rules.ground_truth.input,
        refiner_outputs(),
        f"{OUT}/report/index.html",

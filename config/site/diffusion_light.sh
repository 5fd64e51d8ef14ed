#!/usr/bin/env bash
# Example site command for DiffusionLight (github.com/DiffusionLight/DiffusionLight, README at commit
# 7130ec4). Template (config recon.paper_stack.commands.diffusion_light):
#   config/site/diffusion_light.sh {frame0_dir} {out}
# Needs: DIFFUSION_LIGHT_ROOT (a checkout, conda env diffusionlight; its SDXL models in the Hugging Face
# cache: nothing is downloaded on a node without network, so fill HF_HOME beforehand), a GPU.
# Leaves under {out}: hdr/<clip>.exr (exposure2hdr.py's map of the clip's first frame).
set -euo pipefail
IN=$(realpath "$1"); OUT=$(realpath "$2")
: "${DIFFUSION_LIGHT_ROOT:?set DIFFUSION_LIGHT_ROOT to the DiffusionLight checkout}"
cd "$DIFFUSION_LIGHT_ROOT"
python inpaint.py --dataset "$IN" --output_dir "$OUT/work"
python ball2envmap.py --ball_dir "$OUT/work/square" --envmap_dir "$OUT/work/envmap"
python exposure2hdr.py --input_dir "$OUT/work/envmap" --output_dir "$OUT/hdr"
rm -rf "$OUT/work"   # (its cwd-relative temp_inpaint_iterative/ cache is shared by concurrent jobs: left alone)

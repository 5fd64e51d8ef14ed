#!/usr/bin/env bash
# Example site command for DiffusionRenderer's inverse renderer (github.com/nv-tlabs/cosmos1-diffusion-renderer,
# README at commit a164852). Template (config recon.paper_stack.commands.diffusion_renderer):
#   config/site/diffusion_renderer.sh {frames_root} {out} {num_frames}
# Needs: DIFFUSION_RENDERER_ROOT (a checkout set up as its README says: conda env cosmos-predict1,
# checkpoints/ downloaded there, ~56 GB), a GPU with >= 24 GB. {frames_root} holds exactly this clip's
# frame folder (--group_mode folder renders every sub-folder as a clip). The whole video is rendered
# (--chunk_mode all); the default output 1280x704 stretches a 3:2 video to 16:9, which the backend
# corrects for (recon.paper_stack.dr_unstretch_normals). Leaves under {out}:
# gbuffer_frames/<clip>/<chunk>.<index>.<pass>.jpg (videos are not saved: --save_video=False).
set -euo pipefail
FRAMES_ROOT=$(realpath "$1"); OUT=$(realpath "$2"); N=$3
: "${DIFFUSION_RENDERER_ROOT:?set DIFFUSION_RENDERER_ROOT to the cosmos1-diffusion-renderer checkout}"
cd "$DIFFUSION_RENDERER_ROOT"
FRAMES_PER_CHUNK=57            # the released default; 8n+1 frames per chunk
[ "$N" -eq 1 ] && FRAMES_PER_CHUNK=1
CUDA_HOME=${CUDA_HOME:-${CONDA_PREFIX:-}} PYTHONPATH=$(pwd) python cosmos_predict1/diffusion/inference/inference_inverse_renderer.py \
  --checkpoint_dir checkpoints --diffusion_transformer_dir Diffusion_Renderer_Inverse_Cosmos_7B \
  --dataset_path="$FRAMES_ROOT" --num_video_frames "$FRAMES_PER_CHUNK" --group_mode folder --chunk_mode all \
  --save_video=False --video_save_folder="$OUT"

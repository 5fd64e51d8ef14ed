#!/usr/bin/env bash
# Example site command for MegaSAM (github.com/mega-sam/mega-sam, README and tools/evaluate_demo.sh at
# commit c2e0099). Template (config recon.paper_stack.commands.megasam):
#   config/site/megasam.sh {frames} {out} {clip} {num_frames}
# Needs: MEGASAM_ROOT (a checkout built as its README says: conda env mega_sam, base/ built), its
# checkpoints (Depth-Anything/checkpoints/depth_anything_vitl14.pth, cvd_opt/raft-things.pth,
# checkpoints/megasam_final.pth), a GPU. Every MegaSAM script writes relative to the checkout, so this
# runs there and removes that clip's intermediates (~5-8 MB per frame) on exit, whatever happens.
# Leaves under {out}: outputs_cvd/<clip>_sgd_cvd_hr.npz; for a one-frame clip (MegaSAM's tracker needs
# a warm-up of 8 moving keyframes) only UniDepth's <frame>.npz (the backend's static-camera path).
set -euo pipefail
FRAMES=$(realpath "$1"); OUT=$(realpath "$2"); SEQ=$3; N=$4
: "${MEGASAM_ROOT:?set MEGASAM_ROOT to the mega-sam checkout}"
cd "$MEGASAM_ROOT"
cleanup() {
  rm -rf "Depth-Anything/video_visualization/$SEQ" "UniDepth/outputs/$SEQ" "reconstructions/$SEQ" \
         "outputs/${SEQ}_droid.npz" "cache_flow/$SEQ" "outputs_cvd/${SEQ}_sgd_cvd_hr.npz"
}
trap cleanup EXIT
export PYTHONPATH="${PYTHONPATH:-}:$(pwd)/UniDepth"
python UniDepth/scripts/demo_mega-sam.py --scene-name "$SEQ" --img-path "$FRAMES" --outdir UniDepth/outputs
if [ "$N" -eq 1 ]; then
  mkdir -p "$OUT/UniDepth" && cp -r "UniDepth/outputs/$SEQ" "$OUT/UniDepth/"
  exit 0
fi
python Depth-Anything/run_videos.py --encoder vitl --load-from Depth-Anything/checkpoints/depth_anything_vitl14.pth \
  --img-path "$FRAMES" --outdir "Depth-Anything/video_visualization/$SEQ"
# --disable_vis is required (without it test_demo.py calls an undefined show_image);
# --metric_depth_path is given explicitly (its default carries a trailing space).
python camera_tracking_scripts/test_demo.py --datapath="$FRAMES" --weights=checkpoints/megasam_final.pth \
  --scene_name "$SEQ" --mono_depth_path "$(pwd)/Depth-Anything/video_visualization" \
  --metric_depth_path "$(pwd)/UniDepth/outputs" --disable_vis
python cvd_opt/preprocess_flow.py --datapath="$FRAMES" --model=cvd_opt/raft-things.pth --scene_name "$SEQ" --mixed_precision
python cvd_opt/cvd_opt.py --scene_name "$SEQ" --w_grad 2.0 --w_normal 5.0
mkdir -p "$OUT/outputs_cvd" && cp "outputs_cvd/${SEQ}_sgd_cvd_hr.npz" "$OUT/outputs_cvd/"

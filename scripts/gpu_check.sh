#!/usr/bin/env bash
# The GPU check (run it on a GPU node; about 6-9 minutes). Writes results/bench/gpu_check/gpu_check.json:
#   1. the paper refiner preset rehearsed on CUDA (scripts/rehearse_refiner.py --device cuda: a tiny
#      checkpoint in CogVideoX-5B-I2V's layout, bf16 + fp32 masters, resume, CFG, fused tiling);
#   2. Mitsuba's forward renderer R: cuda_ad_rgb against llvm_ad_rgb on one 720x480 frame at the default
#      proxy.spp, interleaved in one run (benchmarks/proxy_device.py: seconds per frame, the speed ratio,
#      each variant against its own 1024-spp frame, and the two 1024-spp frames against each other;
#      COMPARE_REF=FILE.npy scores them against a frame saved by --save-ref elsewhere, e.g. where the
#      GPU node has no libLLVM for llvm_ad_rgb; HDRI=FILE.exr where bpy's bundled forest.exr is absent);
#   3. the paper preset's optimizer step at full size (benchmarks/refiner_step.py: a random 5.6e9-parameter
#      transformer in CogVideoX-5B-I2V's layout, 49x480x720 clips; peak GPU memory, seconds per step;
#      needs ~11 GB of disk and a >= 120 GB GPU; SKIP_FULL_STEP=1 leaves it out);
#   4. Cycles: OptiX and CUDA against the CPU on one 720x480 frame (seconds, PSNR against the CPU frame).
#   bash scripts/gpu_check.sh            (after bash scripts/setup.sh with a CUDA build of torch)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
OUT=${OUT:-results/bench/gpu_check}
mkdir -p "$OUT"
# a step that fails must not leave the previous run's result to be reported as this run's
rm -rf "$OUT/rehearsal" "$OUT/mitsuba.json" "$OUT/refiner_step.json" "$OUT/cycles_device.json" "$OUT/refiner_step_work"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader > "$OUT/gpu.txt" || echo "no nvidia-smi" > "$OUT/gpu.txt"
"$PY" scripts/rehearse_refiner.py --device cuda --out "$OUT/rehearsal" > "$OUT/rehearsal.log" 2>&1 || echo "rehearsal failed: $OUT/rehearsal.log"
timeout 300 "$PY" benchmarks/proxy_device.py --repeats 5 --start-timeout 120 --out "$OUT/mitsuba.json" --save-ref "$OUT/mitsuba_ref" \
  ${COMPARE_REF:+--compare-ref "$COMPARE_REF"} ${HDRI:+--hdri "$HDRI"} > "$OUT/mitsuba.log" 2>&1 || echo "mitsuba failed: $OUT/mitsuba.log"
if [ -z "${SKIP_FULL_STEP:-}" ]; then
  timeout 420 "$PY" benchmarks/refiner_step.py --size full --device cuda --steps 3 --out "$OUT/refiner_step.json" \
    --work "$OUT/refiner_step_work" > "$OUT/refiner_step.log" 2>&1 || echo "refiner_step failed: $OUT/refiner_step.log"
  rm -rf "$OUT/refiner_step_work"
else
  echo '{"not_run": "skipped: SKIP_FULL_STEP is set"}' > "$OUT/refiner_step.json"
fi
timeout 240 "$PY" benchmarks/cycles_device.py --repeats 1 --devices cpu optix cuda --out "$OUT/cycles_device.json" \
  > "$OUT/cycles.log" 2>&1 || echo "cycles failed: $OUT/cycles.log"
"$PY" - "$OUT" <<'PY'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
def read(name):
    p = out / name
    return json.loads(p.read_text()) if p.is_file() else {"not_run": f"{p} missing (see the .log beside it)"}
report = {"gpu": (out / "gpu.txt").read_text().strip(), "rehearsal": read("rehearsal/rehearsal.json"),
          "mitsuba": read("mitsuba.json"),
          "refiner_step": read("refiner_step.json"), "cycles": read("cycles_device.json")}
(out / "gpu_check.json").write_text(json.dumps(report, indent=1, default=str))
print(f"gpu_check: {out / 'gpu_check.json'}")
PY

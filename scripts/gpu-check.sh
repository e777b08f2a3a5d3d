#!/usr/bin/env bash
# The GPU check: what a user's GPU does with the default scene, in one JSON.
#
#   scripts/gpu-check.sh [BIN] [OUT]      (BIN may be gzipped: BIN.gz)
#
# Runs on a bare GPU machine with no Rust toolchain and no network: BIN is a prebuilt
# `--features wgpu` release binary (default target/release/talkin; strip it to carry it),
# and when the machine has no Vulkan loader, the loader's Debian packages in $GL_DEBS
# (default .gl; `apt-get download libvulkan1`) are unpacked first. Stages, each under its
# own time limit so that one slow stage cannot eat the others:
#
#   1. synthesise the default scene (CPU);
#   2. a cold start: the first 30 steps of the demo's recipe on a GPU (`talkin demo
#      --device wgpu`: MSE + 0.05 CE, 4096 rays a step) in a fresh process, where
#      every kernel is compiled and autotuned (cubecl and the driver cache both, so the
#      later processes start warm); its time is the one-off cost a user pays once;
#   3. that recipe trained on the GPU for 60 s (InstantAvatar's budget), test_same
#      scored; then, with GPU_CHECK_MINUTES above 1, resumed to that many minutes in all
#      and scored again; then the same 60 s at each batch in GPU_CHECK_BATCHES (rays a
#      step, e.g. "512 8192"), each scored;
#   4. a warm start: 30 steps in another fresh process, every autotune choice cached,
#      so what any later process pays to compile its kernels;
#   5. `bench device`, fast preset at the recipe's 4096 rays a step: step time, samples/s,
#      the host sampler's share of a step, 540x540 render fps (30 untimed steps first:
#      a fresh process compiles its kernels again), and the 540x540 fps of stage 3's
#      trained avatar (its grid updated, samples routed to its face and hand nets, where
#      the bench's fresh field's are not);
#   6. `bench device`, paper preset at 32,768 rays a step (the paper's batch);
#   7. with GPU_CHECK_COMPOSED=1, stage 5 again with the MLPs as composed burn ops
#      (`--mlp-fused off`), the baseline of the fused MLP kernels in the same run.
#
# Everything lands in OUT (default out/gpu-check); OUT/gpu-check.json gathers the
# numbers, and each stage's log is beside it. A stage that fails or runs out of time is
# recorded as such and the next one runs. The limits add up to 8 minutes at the default
# 1 minute of training (stage 7 adds one). Exit status: 0 when every stage finished.
set -uo pipefail

BIN=${1:-target/release/talkin}
OUT=${2:-out/gpu-check}
GL_DEBS=${GL_DEBS:-.gl}
MINUTES=${GPU_CHECK_MINUTES:-1}
BATCHES=${GPU_CHECK_BATCHES:-}
DEVICE=${GPU_CHECK_DEVICE:-wgpu}
COMPOSED=${GPU_CHECK_COMPOSED:-0}
# cubecl's autotune at its lightest unless the caller chose a level: at the default level
# a fresh H200 did not get through the first 30 steps in 2 minutes (docs/design.md,
# "Devices").
export CUBECL_AUTOTUNE_LEVEL=${CUBECL_AUTOTUNE_LEVEL:-minimal}

# A gzipped binary is unpacked first: stripped, the wgpu build is about 110 MB, gzipped 32.
if [[ "$BIN" == *.gz ]] && [ -f "$BIN" ]; then
  unpacked=$(mktemp -d)/talkin
  if ! { gunzip -c "$BIN" >"$unpacked" && chmod +x "$unpacked"; }; then
    echo "gpu-check: cannot unpack $BIN" >&2
    exit 2
  fi
  BIN=$unpacked
fi
if [ ! -x "$BIN" ]; then
  echo "gpu-check: $BIN is not an executable talkin binary (build one with" \
    "cargo build --release --features wgpu)" >&2
  exit 2
fi
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

# The Vulkan loader, and NVIDIA's driver manifest where the container keeps it apart.
if ! ldconfig -p 2>/dev/null | grep -q 'libvulkan\.so\.1'; then
  if compgen -G "$GL_DEBS/*.deb" >/dev/null; then
    for f in "$GL_DEBS"/*.deb; do dpkg -x "$f" /; done
    ldconfig
  else
    echo "gpu-check: no Vulkan loader (libvulkan.so.1) and no packages in $GL_DEBS" >&2
  fi
fi
nvidia_icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$nvidia_icd" ]; then
  export VK_DRIVER_FILES=$nvidia_icd
fi

status=0
stages=()
# stage NAME LIMIT_S CMD...: runs CMD under a time limit, logs to OUT/NAME.log.
stage() {
  local name=$1 limit=$2
  shift 2
  local start end rc
  start=$(date +%s.%N)
  echo "== $name (limit ${limit}s): $*"
  timeout --kill-after=10 "$limit" "$@" >"$OUT/$name.log" 2>&1
  rc=$?
  end=$(date +%s.%N)
  local secs
  secs=$(awk -v a="$start" -v b="$end" 'BEGIN { printf "%.1f", b - a }')
  local outcome=ok
  if [ $rc -eq 124 ] || [ $rc -eq 137 ]; then outcome=timed_out; elif [ $rc -ne 0 ]; then outcome=failed; fi
  [ $rc -eq 0 ] || status=1
  echo "   $outcome in ${secs}s"
  [ $rc -eq 0 ] || tail -n 5 "$OUT/$name.log"
  stages+=("{\"stage\": \"$name\", \"outcome\": \"$outcome\", \"exit\": $rc, \"seconds\": $secs}")
}

# The file's contents, or null when it is missing.
json_or_null() { if [ -s "$1" ]; then cat "$1"; else echo null; fi; }

data=$OUT/data
stage synth 20 "$BIN" -q synth --out "$data"
# The demo's recipe on a GPU (`talkin demo --device wgpu`): MSE + 0.05 CE, 4096 rays a
# step, no LPIPS patch.
BATCH=4096
recipe=(--device "$DEVICE" --patches 0 --batch "$BATCH" --checkpoint-every 1000000)
stage cold-start 90 "$BIN" -q train --data "$data" --out "$OUT/cold" --force --steps 30 "${recipe[@]}"
stage train-60s 90 "$BIN" -q train --data "$data" --out "$OUT/run" --force --minutes 1 "${recipe[@]}"
stage eval-60s 45 "$BIN" -q eval --run "$OUT/run" --data "$data" --split test_same \
  --json "$OUT/eval_60s.json" --device "$DEVICE"
if [ "$MINUTES" -gt 1 ]; then
  # `--minutes` on a resumed run is the new total.
  stage train-more $(((MINUTES - 1) * 60 + 45)) "$BIN" -q train --data "$data" --out "$OUT/run" \
    --resume --minutes "$MINUTES" "${recipe[@]}"
  stage eval-more 120 "$BIN" -q eval --run "$OUT/run" --data "$data" --split test_same \
    --json "$OUT/eval_more.json" --device "$DEVICE"
fi
batch_evals=()
for b in $BATCHES; do
  stage "train-60s-b$b" 90 "$BIN" -q train --data "$data" --out "$OUT/run-b$b" --force --minutes 1 \
    --device "$DEVICE" --patches 0 --batch "$b" --checkpoint-every 1000000
  stage "eval-60s-b$b" 45 "$BIN" -q eval --run "$OUT/run-b$b" --data "$data" --split test_same \
    --json "$OUT/eval_60s_b$b.json" --device "$DEVICE"
  batch_evals+=("\"$b\": {\"eval\": $(json_or_null "$OUT/eval_60s_b$b.json"), \"train_log_tail\": \"$(tail -n 1 "$OUT/run-b$b/train_log.csv" 2>/dev/null)\"}")
done
stage warm-start 45 "$BIN" -q train --data "$data" --out "$OUT/warm" --force --steps 30 "${recipe[@]}"
avatar=()
[ -d "$OUT/run/checkpoint" ] && avatar=(--avatar "$OUT/run")
stage bench-fast 70 "$BIN" -q bench device --data "$data" --out "$OUT/bench-fast" \
  --devices "$DEVICE" --presets fast --batch "$BATCH" --warmup 30 --steps 20 --renders 3 "${avatar[@]}"
stage bench-paper 120 "$BIN" -q bench device --data "$data" --out "$OUT/bench-paper" \
  --devices "$DEVICE" --presets paper --batch 32768 --warmup 3 --steps 5 --renders 2
if [ "$COMPOSED" = 1 ]; then
  stage bench-fast-composed 60 "$BIN" -q bench device --data "$data" \
    --out "$OUT/bench-fast-composed" --devices "$DEVICE" --presets fast --batch "$BATCH" --warmup 30 \
    --steps 20 --renders 3 --mlp-fused off
fi

adapter=$(nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>/dev/null | head -n 1)
{
  echo "{"
  echo "  \"gpu\": \"${adapter:-unknown}\","
  echo "  \"device\": \"$DEVICE\","
  echo "  \"minutes_in_all\": $MINUTES,"
  echo "  \"stages\": ["
  for i in "${!stages[@]}"; do
    sep=,
    [ "$i" -eq $((${#stages[@]} - 1)) ] && sep=
    echo "    ${stages[$i]}$sep"
  done
  echo "  ],"
  echo "  \"bench_fast\": $(json_or_null "$OUT/bench-fast/device.json"),"
  echo "  \"bench_paper\": $(json_or_null "$OUT/bench-paper/device.json"),"
  echo "  \"bench_fast_composed_mlps\": $(json_or_null "$OUT/bench-fast-composed/device.json"),"
  echo "  \"eval_test_same_60s\": $(json_or_null "$OUT/eval_60s.json"),"
  echo "  \"eval_test_same_more\": $(json_or_null "$OUT/eval_more.json"),"
  echo "  \"larger_batches_60s\": {$(IFS=,; echo "${batch_evals[*]}")},"
  echo "  \"autotune_level\": \"$CUBECL_AUTOTUNE_LEVEL\","
  echo "  \"train_log_tail\": \"$(tail -n 1 "$OUT/run/train_log.csv" 2>/dev/null)\""
  echo "}"
} >"$OUT/gpu-check.json.tmp" && mv "$OUT/gpu-check.json.tmp" "$OUT/gpu-check.json"
echo "gpu-check: $OUT/gpu-check.json"
exit $status

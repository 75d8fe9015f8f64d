#!/usr/bin/env bash
# Issues 9 and 45: every GPU measurement and CUDA check of depthsense in one run (≤ 9.5 min on
# one H200), the science first.
#
# On the CPU machine (Rust toolchain):   make gpu-bundle        # → .gpu/ (< 64 MiB, git-ignored)
# On the GPU machine (Python 3.12 + torch 2.11.0+cu130, no Rust), from the repository root with
# .gpu/ brought along:                   bash .gpu/gpu-check.sh [--out DIR]
# Results go to $OUT (or --out DIR, default ./gpu-check-out): at most 8 files —
#   science.json      issue 45: rgb vs late-sam, `paper` at 800x350, two seeds, on a ≈ 3,000-image
#                     world made here (scripts/gpu-science.sh: world, iterations, wall times, test
#                     metrics, the margin and its paired statistics)
#   env.json          machine, GPU, driver, torch, ldd check, bundle, every step's status/time
#   bench_ours.json   `depthsense bench model` rows (released/paper × fp32/bf16/bf16+channels-last)
#   bench_torch.json  scripts/torch_reference.py rows (same variants × ordinal released/efficient)
#   train.json        `train` fp32 vs --amp (val RMSE), `bench train` loader, one NCCL rank vs
#                     one process (losses, all-reduce line)
#   demo.json         `depthsense demo --device cuda` summary (fusion margin) or how far it got
#   summary.json      the table printed at the end: ratios ours/PyTorch, targets, checks (bf16 on
#                     the trained checkpoint, deprecation lines, NCCL, onnxruntime CUDA)
#   log.txt           every command and its output (tail-truncated)
# Steps run most important first, each under `timeout`, within a total budget (--budget, default
# 570 s): a step that no longer fits is recorded as skipped, and every JSON is written even then.
# Order: science (its own share, --science-budget) → bf16 on the trained checkpoint → NCCL →
# onnxruntime's CUDA provider → the inference graph, predict's pipeline and the per-operator
# profile (issue 44) → the model benchmarks → train fp32/amp → bench train → demo.
# The deprecation check reads the whole log at the end.
#
# Options:
#   --out DIR          where the results go (default: $OUT, else ./gpu-check-out)
#   --budget SECONDS   total time budget (default 550; the dry run: 450)
#   --science-budget S the science step's share (default 350, at most the time left − 40; the
#                      dry run: 150)
#   --demo-epochs N    epochs of each demo model (default 4; 0 = the CUDA plan's own 30)
#   --only REGEX       run only the steps whose name matches (bash =~), e.g. 'demo' or
#                      'released' to rerun part of the check within a slot; names: science,
#                      bf16_trained, nccl_single, nccl_rank, ort_cuda, infer_<preset>[_cl],
#                      predict_pipeline, predict_graph, predict_tokens[_world], profile_released,
#                      ours_<preset>_<variant>,
#                      torch_<preset>, train_fp32, train_amp, bench_train, demo
#   --cpu-dry-run      prove the script on a CPU machine: tiny preset, small sizes, CPU device,
#                      no CUDA-only checks (ldd/nvidia-smi recorded, not required); the test
#                      suite runs it (crates/cli/tests/gpu_check.rs)
#   --make-bundle DIR  (CPU machine) build the bundle: stripped release binary, a small prepared
#                      synthetic world, these scripts; prints its size. Used by `make gpu-bundle`.
# The binary: $DEPTHSENSE_BIN, else beside this script, .gpu/, target/release.
set -u -o pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
REPO="$(cd "$HERE/.." && pwd)"
DRY=0
BUDGET=""
SCI_BUDGET=""
DEMO_EPOCHS=4
OUTDIR="${OUT:-}"
MAKE_BUNDLE=""
ONLY=""
while [ $# -gt 0 ]; do
  case "$1" in
    --cpu-dry-run) DRY=1 ;;
    --out) OUTDIR="$2"; shift ;;
    --budget) BUDGET="$2"; shift ;;
    --science-budget) SCI_BUDGET="$2"; shift ;;
    --demo-epochs) DEMO_EPOCHS="$2"; shift ;;
    --make-bundle) MAKE_BUNDLE="$2"; shift ;;
    --only) ONLY="$2"; shift ;;
    -h|--help) sed -n '2,45p' "${BASH_SOURCE[0]}"; exit 0 ;;
    *) echo "gpu-check: unknown option $1" >&2; exit 2 ;;
  esac
  shift
done

# Python with torch: $PYTHON, python3, or the workspace .venv (CPU machine).
PY="${PYTHON:-python3}"
if ! "$PY" -c 'import torch' 2>/dev/null; then
  for c in "$REPO/.venv/bin/python" "$HERE/../.venv/bin/python"; do
    if [ -x "$c" ] && "$c" -c 'import torch' 2>/dev/null; then PY="$c"; break; fi
  done
fi

# SOURCES_PY list REPO < paths: "sha256  path" of each file; SOURCES_PY check REPO LISTING: the
# paths whose file differs from the listing (or is missing), "N path path …" (at most five).
SOURCES_PY='
import hashlib, os, sys
def digest(path):
    try:
        with open(path, "rb") as f:
            return hashlib.sha256(f.read()).hexdigest()
    except OSError:
        return None
mode, repo = sys.argv[1], sys.argv[2]
if mode == "list":
    for p in sys.stdin.read().split("\0"):
        if p:
            print(digest(os.path.join(repo, p)), p, sep="  ")
else:
    bad = []
    for line in open(sys.argv[3], encoding="utf-8"):
        want, p = line.rstrip("\n").split("  ", 1)
        if digest(os.path.join(repo, p)) != want:
            bad.append(p)
    print(len(bad), *bad[:5])
'

# ------------------------------------------------------------------------------------------
# --make-bundle DIR (CPU machine)
if [ -n "$MAKE_BUNDLE" ]; then
  set -e
  B="$MAKE_BUNDLE"
  SRC_BIN="${DEPTHSENSE_BIN:-$REPO/target/release/depthsense}"
  [ -x "$SRC_BIN" ] || { echo "no release binary at $SRC_BIN (make build)" >&2; exit 2; }
  WORLD_TMP="${GPU_BUNDLE_WORLD:-$REPO/runs/gpu-bundle-world}"
  mkdir -p "$B"
  rm -rf "$B/prepared"
  # Both binaries: `depthsense` (torch-free front) hands the network commands to
  # `depthsense-net` beside it.
  for bin in depthsense depthsense-net; do
    SRC="$(dirname "$SRC_BIN")/$bin"
    [ -x "$SRC" ] || { echo "no release binary at $SRC (make build)" >&2; exit 2; }
    cp "$SRC" "$B/$bin.tmp" && strip "$B/$bin.tmp" && mv "$B/$bin.tmp" "$B/$bin"
  done
  cp "$REPO/scripts/gpu-check.sh" "$REPO/scripts/gpu-science.sh" "$REPO/scripts/science_json.py" \
    "$REPO/scripts/ort_latency.py" \
    "$REPO/scripts/torch_reference.py" "$REPO/python/depthsense_torch.py" "$B/"
  chmod +x "$B/gpu-check.sh" "$B/gpu-science.sh" "$B/depthsense" "$B/depthsense-net"
  # What the bundle was built from: every tracked source file's digest, so that the run on the
  # GPU machine refuses a bundle older than the tree it arrives with (sources.txt).
  git -C "$REPO" ls-files -z crates scripts python Cargo.toml Cargo.lock \
    | "$PY" -c "$SOURCES_PY" list "$REPO" > "$B/sources.txt"
  # A small world: 10 scenes × 5 keyframes (val/test scenes held out by the loader's rule),
  # prepared like the demo (K = 2 lidar sweeps for the dense target).
  "$B/depthsense" synth --out "$WORLD_TMP" --force --scenes 10 --keyframes-per-scene 5 --seed 7 \
    --jobs "${JOBS:-0}" >/dev/null
  "$B/depthsense" prepare --dataroot "$WORLD_TMP" --version v1.0-synth --split all \
    --lidar-sweeps 2 --out "$B/prepared" --jobs "${JOBS:-0}" >/dev/null
  rm -rf "$WORLD_TMP"
  {
    echo "{"
    echo "  \"built\": \"$(date -u +%Y-%m-%dT%H:%M:%SZ)\","
    echo "  \"git_commit\": \"$(git -C "$REPO" rev-parse HEAD 2>/dev/null || echo unknown)\","
    echo "  \"git_dirty\": $( [ -z "$(git -C "$REPO" status --porcelain --untracked-files=no 2>/dev/null)" ] && echo false || echo true),"
    echo "  \"binary_sha256\": \"$(sha256sum "$B/depthsense-net" | cut -d' ' -f1)\","
    echo "  \"binary_built\": \"$(date -u -r "$SRC_BIN" +%Y-%m-%dT%H:%M:%SZ)\","
    echo "  \"world\": \"synth --scenes 10 --keyframes-per-scene 5 --seed 7; prepare --lidar-sweeps 2\""
    echo "}"
  } > "$B/bundle.json"
  SIZE_KB=$(du -sk "$B" | cut -f1)
  echo "bundle $B: $((SIZE_KB / 1024)) MiB ($(find "$B/prepared" -name meta.json | wc -l) prepared samples)"
  du -sh "$B"/* | sed 's/^/  /'
  if [ "$SIZE_KB" -ge $((64 * 1024)) ]; then
    echo "bundle is over 64 MiB: the device tool's carry limit" >&2
    exit 1
  fi
  exit 0
fi

# ------------------------------------------------------------------------------------------
# The run
# The GPU budget leaves the device call's 600 s room for what runs outside it: python's import
# of torch before T0, the summary after, each step's --kill-after.
if [ "$DRY" = 1 ]; then : "${BUDGET:=450}" "${SCI_BUDGET:=150}"; else : "${BUDGET:=550}" "${SCI_BUDGET:=350}"; fi

T0=$(date +%s)
[ -n "$OUTDIR" ] || OUTDIR="$PWD/gpu-check-out"
mkdir -p "$OUTDIR"
OUTDIR="$(cd "$OUTDIR" && pwd)"
S="$(mktemp -d "${TMPDIR:-/tmp}/gpu-check.XXXXXX")"
LOG="$OUTDIR/log.txt"
: > "$LOG"
STEPS="$S/steps.tsv"
: > "$STEPS"

log() { echo "[gpu-check +$(( $(date +%s) - T0 ))s] $*" | tee -a "$LOG" >&2; }

BIN="${DEPTHSENSE_BIN:-}"
for c in "$HERE/depthsense" "$REPO/.gpu/depthsense" "$REPO/target/release/depthsense"; do
  [ -z "$BIN" ] || break
  if [ -x "$c" ]; then BIN="$c"; break; fi
done
ORT_PY=""
for c in "$HERE/ort_latency.py" "$REPO/scripts/ort_latency.py"; do
  if [ -f "$c" ]; then ORT_PY="$c"; break; fi
done
REF=""
for c in "$HERE/torch_reference.py" "$REPO/scripts/torch_reference.py"; do
  if [ -f "$c" ]; then REF="$c"; break; fi
done
DATA=""
for c in "$HERE/prepared" "$REPO/.gpu/prepared"; do
  if [ -f "$c/index.json" ]; then DATA="$c"; break; fi
done
BUNDLE_JSON=""
[ -f "$HERE/bundle.json" ] && BUNDLE_JSON="$HERE/bundle.json"

TORCH_LIB="$("$PY" -c 'import torch,os;print(os.path.dirname(torch.__file__))' 2>/dev/null)/lib"
export LD_LIBRARY_PATH="$TORCH_LIB${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
log "python $PY, torch lib $TORCH_LIB, binary ${BIN:-none}, reference ${REF:-none}, data ${DATA:-none}, out $OUTDIR, budget ${BUDGET}s, dry run $DRY"

fail() {
  log "FATAL: $*"
  "$PY" -c 'import json,sys; print(json.dumps({"fatal": sys.argv[1]}))' "$*" > "$OUTDIR/env.json" \
    2>/dev/null || echo '{"fatal": "see log.txt"}' > "$OUTDIR/env.json"
  exit 3
}
[ -n "$BIN" ] || fail "no depthsense binary (make gpu-bundle on the CPU machine, bring .gpu/)"
# A bundle carried beside a newer tree would time old code: refused in seconds, not after the
# budget is spent (the tree's files travel with every device call).
if [ -f "$HERE/sources.txt" ] && [ -f "$REPO/Cargo.lock" ]; then
  STALE="$("$PY" -c "$SOURCES_PY" check "$REPO" "$HERE/sources.txt")"
  [ "${STALE%% *}" = 0 ] || fail "the bundle in $HERE was built from other sources than this tree (${STALE%% *} files differ: ${STALE#* }): run make gpu-bundle and carry it again"
fi
[ -n "$REF" ] || fail "no torch_reference.py"
"$PY" -c 'import torch' 2>/dev/null || fail "python $PY cannot import torch"

# ldd: libtorch_cuda.so must be linked and resolved, or the binary runs on the CPU silently.
# (`depthsense` is the torch-free front; the network commands run in depthsense-net beside it.)
NET_BIN="$(dirname "$BIN")/depthsense-net"
if command -v ldd >/dev/null; then
  ldd "$NET_BIN" > "$S/ldd.txt" 2>&1
else
  echo "ldd: not installed" > "$S/ldd.txt"
fi
cat "$S/ldd.txt" >> "$LOG"
LDD_CUDA="$(grep -E 'libtorch_cuda\.so' "$S/ldd.txt" | head -1 | sed 's/^[[:space:]]*//')"
LDD_MISSING="$(grep -c 'not found' "$S/ldd.txt" || true)"
if [ "$DRY" = 0 ]; then
  if [ -z "$LDD_CUDA" ] || echo "$LDD_CUDA" | grep -q 'not found'; then
    fail "ldd: libtorch_cuda.so is not linked/resolved by $NET_BIN (got: '${LDD_CUDA:-nothing}'): the run would be on the CPU"
  fi
  [ "$LDD_MISSING" = 0 ] || fail "ldd: $LDD_MISSING libraries not found (see log.txt)"
  "$PY" -c 'import torch,sys; sys.exit(0 if torch.cuda.is_available() else 1)' \
    || fail "torch.cuda.is_available() is False"
  # The binary itself on the GPU (`--device cuda` is an error, never a CPU fall-back, without one).
  if ! timeout 120 "$BIN" bench model --config tiny --device cuda --height 64 --width 128 \
      --batch-forward 1 --batch-train 1 --warmup-runs 0 --repeats 1 > "$S/smoke.txt" 2>&1; then
    cat "$S/smoke.txt" >> "$LOG"
    fail "depthsense bench model --device cuda failed: $(tail -c 300 "$S/smoke.txt" | tr '\n"' '  ')"
  fi
  cat "$S/smoke.txt" >> "$LOG"
fi
GPU_INFO="$(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null | head -1)"
CUDA_DRV="$(nvidia-smi 2>/dev/null | grep -o 'CUDA Version: [0-9.]*' | head -1)"
nvidia-smi >> "$LOG" 2>&1 || true
log "GPU: ${GPU_INFO:-none} ${CUDA_DRV}; ldd: ${LDD_CUDA:-no libtorch_cuda.so}"

# step NAME CAP_SECONDS MIN_SECONDS cmd... : runs under timeout min(CAP, remaining budget);
# skipped when less than MIN_SECONDS remain. Output → $S/NAME.log (and log.txt).
step() {
  local name="$1" cap="$2" min="$3"; shift 3
  local now left t rc start
  if [ -n "$ONLY" ] && ! [[ "$name" =~ $ONLY ]]; then
    printf '%s\tnot selected\t0\t--only %s\n' "$name" "$ONLY" >> "$STEPS"
    return 0
  fi
  now=$(date +%s); left=$(( BUDGET - (now - T0) ))
  if [ "$left" -lt "$min" ]; then
    log "SKIP $name: ${left}s left, needs ≥ ${min}s"
    printf '%s\tskipped\t0\t%s\n' "$name" "out of budget (${left}s left)" >> "$STEPS"
    return 0
  fi
  t=$cap; [ "$t" -le "$left" ] || t=$left
  log "RUN  $name (limit ${t}s): $*"
  start=$(date +%s)
  timeout --kill-after=10 "$t" "$@" > "$S/$name.log" 2>&1
  rc=$?
  { echo "----- $name (rc $rc) -----"; tail -c 20000 "$S/$name.log"; } >> "$LOG"
  local st=ok
  [ "$rc" = 0 ] || st="rc $rc"
  [ "$rc" = 124 ] || [ "$rc" = 137 ] && st="timeout after ${t}s"
  log "DONE $name: $st in $(( $(date +%s) - start ))s"
  printf '%s\t%s\t%s\t%s\n' "$name" "$st" "$(( $(date +%s) - start ))" "$*" >> "$STEPS"
  return 0
}

# Sizes.
if [ "$DRY" = 1 ]; then
  # The dry run proves the code paths, not the timings: one warm-up, two timed passes.
  DEV=cpu; H=176; W=400; BF=1; BT=2; WU=1; REP=2; PROF_RUNS=(--warmup-runs 1 --repeats 1)
  PRESETS="tiny"; VARIANTS="fp32 bf16-cl"
  THR="--threads 1"
  TRAIN_ARGS=(--config tiny --epochs 1 --batch-size 2 --max-batches-per-epoch 2 --max-val-samples 4 --set input-downscale=2 --jobs 1)
  BTRAIN_ARGS=(--config tiny --batch-size 2 --iterations 2 --warmup-runs 1 --loader-batches 2 --set input-downscale=2 --jobs 1)
  DEMO_ARGS=(--quick --device cpu --jobs 1)
  NCCL_ARGS=(--config tiny --set dropout=0 --epochs 1 --batch-size 2 --max-batches-per-epoch 3 --max-val-samples 2 --set input-downscale=2 --jobs 1)
  CAP_OURS=120; CAP_TORCH=240; CAP_TRAIN=240; CAP_BTRAIN=180; CAP_DEMO=400
  PROFILE_PRESET=tiny; TOK_SCENES=1
else
  DEV=cuda; H=350; W=800; BF=3; BT=8; WU=3; REP=10
  PRESETS="released paper"; VARIANTS="bf16-cl fp32 bf16"
  THR=""
  TRAIN_ARGS=(--config tiny --epochs 8 --batch-size 8 --jobs 0)
  BTRAIN_ARGS=(--config paper --batch-size 8 --iterations 10 --warmup-runs 3 --loader-batches 12 --jobs 0)
  DEMO_ARGS=(--device cuda --jobs 0)
  NCCL_ARGS=(--config paper --set dropout=0 --epochs 1 --batch-size 8 --max-batches-per-epoch 20 --max-val-samples 8 --jobs 0)
  [ "$DEMO_EPOCHS" = 0 ] || DEMO_ARGS+=(--epochs "$DEMO_EPOCHS")
  # H200, 2026-12-04: ours 15–41 s a variant, PyTorch 62 s (paper) and > 150 s (released).
  CAP_OURS=75; CAP_TORCH=200; CAP_TRAIN=60; CAP_BTRAIN=60; CAP_DEMO=240
  PROFILE_PRESET=released; PROF_RUNS=(--warmup-runs 2 --repeats 3); TOK_SCENES=6
fi

ours() {  # ours PRESET VARIANT
  local p="$1" v="$2" prec="${2%-cl}" cl=()
  [ "$v" = "$prec" ] || cl=(--channels-last)
  step "ours_${p}_${v}" "$CAP_OURS" 20 "$BIN" bench model --config "$p" --device "$DEV" \
    --precision "$prec" "${cl[@]}" --height "$H" --width "$W" --batch-forward "$BF" \
    --batch-train "$BT" --warmup-runs "$WU" --repeats "$REP" $THR --out "$S/ours_${p}_${v}.json"
}
torchref() {  # torchref PRESET : every variant × both ordinal modes in one process
  local p="$1"
  step "torch_${p}" "$CAP_TORCH" 30 "$PY" "$REF" --config "$p" --device "$DEV" \
    --variants "$(echo $VARIANTS | tr ' ' ',')" --ordinal released,efficient \
    --height "$H" --width "$W" --batch-forward "$BF" --batch-train "$BT" --warmup-runs "$WU" \
    --repeats "$REP" $THR --out "$S/torch_${p}.json"
}

# 1. Science (issue 45), first, with its own share of the budget: rgb vs late-sam at GPU scale.
SCI_SH=""
for c in "$HERE/gpu-science.sh" "$REPO/scripts/gpu-science.sh"; do
  if [ -f "$c" ]; then SCI_SH="$c"; break; fi
done
SCI_OUT="$S/science"
SCI_DRY=(); [ "$DRY" = 1 ] && SCI_DRY=(--cpu-dry-run)
if [ -n "$SCI_SH" ]; then
  export PYTHON="$PY"
  # Its own budget within the time left, so that its inner timeouts end before the step's outer
  # one (an outer timeout does not reach the inner ones' process groups: runs would go on
  # training under every later step).
  SCI_MAX=$(( BUDGET - ($(date +%s) - T0) - 40 ))
  [ "$SCI_BUDGET" -le "$SCI_MAX" ] || SCI_BUDGET=$SCI_MAX
  step science $(( SCI_BUDGET + 30 )) 60 bash "$SCI_SH" --out "$SCI_OUT" \
    --budget "$SCI_BUDGET" --bin "$BIN" --device "$DEV" "${SCI_DRY[@]}"
else
  printf 'science\tskipped\t0\tno gpu-science.sh\n' >> "$STEPS"
fi
[ -f "$SCI_OUT/science.json" ] && cp "$SCI_OUT/science.json" "$OUTDIR/science.json"
SCI_CKPT="$("$PY" -c 'import json,sys; print(json.load(open(sys.argv[1])).get("checkpoint_for_bf16") or "")' "$SCI_OUT/science.json" 2>/dev/null)"
# The science world serves the training steps when no bundled world came along (the dry run).
if [ -z "$DATA" ] && [ -f "$SCI_OUT/work/prepared/index.json" ]; then DATA="$SCI_OUT/work/prepared"; fi

# 2. bf16 agreement on the trained `paper` checkpoint of step 1 (late-sam, seed 0), not on
#    random weights.
if [ -n "$SCI_CKPT" ]; then
  step bf16_trained 60 15 "$BIN" bench model --config "$SCI_CKPT" --device "$DEV" \
    --precision bf16 --channels-last --height "$H" --width "$W" --batch-forward "$BF" \
    --batch-train 0 --warmup-runs "$WU" --repeats 3 $THR --out "$S/bf16_trained.json"
else
  printf 'bf16_trained\tskipped\t0\tno trained checkpoint from the science step\n' >> "$STEPS"
fi

# 3. NCCL (never run before): one rank of `train --nproc 1` on the job's backend (NCCL on CUDA,
#    Gloo on the CPU) against one plain process, same seed, dropout off (a plain process draws
#    dropout from libtorch's generator, ranks from per-sample seeds); the all-reduce line.
if [ -n "$DATA" ]; then
  for m in single rank; do
    np=(); [ "$m" = rank ] && np=(--nproc 1)
    step "nccl_$m" 60 15 "$BIN" train --data "$DATA" --device "$DEV" --seed 0 \
      "${NCCL_ARGS[@]}" "${np[@]}" --out "$S/nccl_$m"
  done
else
  printf 'nccl_single\tskipped\t0\tno data\nnccl_rank\tskipped\t0\tno data\n' >> "$STEPS"
fi

# 4. onnxruntime's CUDA provider (CPU provider in the dry run) on the trained checkpoint's graph.
ORT_CUDA=1
if [ "$DRY" = 0 ] && ! "$PY" -c 'import onnxruntime as o,sys; sys.exit("CUDAExecutionProvider" not in o.get_available_providers())' 2>/dev/null; then
  ORT_CUDA=0
fi
if [ "$ORT_CUDA" = 0 ]; then
  printf 'ort_cuda\tskipped\t0\tonnxruntime without its CUDA provider here (the CPU build, or none)\n' >> "$STEPS"
elif [ -n "$SCI_CKPT" ]; then
  step ort_cuda 90 20 bash -c '"$1" export --checkpoint "$2" --format onnx --out "$3/model.onnx" \
      --python "$4" && "$4" "$5" --onnx "$3/model.onnx" --device "$6" --batch "$7" --height "$8" \
      --width "$9" --out "$3/ort_cuda.json"' _ "$BIN" "$SCI_CKPT" "$S" "$PY" "$ORT_PY" "$DEV" \
      "$BF" "$H" "$W"
else
  printf 'ort_cuda\tskipped\t0\tno trained checkpoint from the science step\n' >> "$STEPS"
fi

# 5. Issue 44's inference rows: the inference graph (BatchNorm folded into the convs) of each
#    preset, fp32 forward; `predict` over the science world's test split on the trained
#    checkpoint (images/s against the network alone, per-batch latency); PyTorch's per-operator
#    profile of the released network's training step in NCHW and channels-last.
for p in $PRESETS; do
  # The inference graph's forward, and its forward + decode replayed from a CUDA graph (the
  # bundle is built with the feature cuda-graphs; on the CPU that row runs eagerly and says so).
  step "infer_$p" "$CAP_OURS" 20 "$BIN" bench model --config "$p" --device "$DEV" \
    --inference-graph --cuda-graph --height "$H" --width "$W" --batch-forward "$BF" \
    --batch-train 0 --warmup-runs "$WU" --repeats "$REP" $THR --out "$S/infer_$p.json"
  # The same graph channels-last: the inference graph keeps NCHW on CUDA until this row says
  # channels-last is faster there (on the CPU it is, and the graph uses it).
  step "infer_${p}_cl" "$CAP_OURS" 20 "$BIN" bench model --config "$p" --device "$DEV" \
    --inference-graph --channels-last --height "$H" --width "$W" --batch-forward "$BF" \
    --batch-train 0 --warmup-runs "$WU" --repeats "$REP" $THR --out "$S/infer_${p}_cl.json"
done
if [ -n "$SCI_CKPT" ]; then
  step predict_pipeline 90 15 "$BIN" predict --checkpoint "$SCI_CKPT" \
    --data "$SCI_OUT/work/prepared" --split test --format npy --out "$S/preds" --device "$DEV"
  step predict_graph 90 15 "$BIN" predict --checkpoint "$SCI_CKPT" --cuda-graph \
    --data "$SCI_OUT/work/prepared" --split test --format npy --out "$S/preds_graph" --device "$DEV"
  # A list of raw frames (sample tokens of a small world of its own): loader threads build
  # each frame from the raw files while the network runs (images/s against the network alone).
  step predict_tokens_world 60 10 "$BIN" synth --out "$S/tok_world" --scenes "$TOK_SCENES" \
    --keyframes-per-scene 10 --seed 44 --lean --jobs 0
  "$PY" -c 'import json,sys; print("\n".join(s["token"] for s in json.load(open(sys.argv[1]))))' \
    "$S/tok_world/v1.0-synth/sample.json" > "$S/tokens.txt" 2>/dev/null || : > "$S/tokens.txt"
  step predict_tokens 90 15 "$BIN" predict --checkpoint "$SCI_CKPT" --dataroot "$S/tok_world" \
    --version v1.0-synth --tokens "$S/tokens.txt" --out "$S/preds_tokens" --device "$DEV"
  rm -rf "$S/tok_world" "$S/preds_tokens"
else
  printf 'predict_pipeline\tskipped\t0\tno trained checkpoint from the science step\n' >> "$STEPS"
  printf 'predict_graph\tskipped\t0\tno trained checkpoint from the science step\n' >> "$STEPS"
  printf 'predict_tokens\tskipped\t0\tno trained checkpoint from the science step\n' >> "$STEPS"
fi
step profile_released 150 30 "$PY" "$REF" --config "$PROFILE_PRESET" --device "$DEV" \
  --profile-train --batch-train "$BT" --height "$H" --width "$W" "${PROF_RUNS[@]}" \
  $THR --out "$S/profile_released.json"

# 6. The model benchmarks, released first (issue 9's targets), ours then PyTorch.
for p in $PRESETS; do
  for v in $VARIANTS; do ours "$p" "$v"; done
  torchref "$p"
done
# 7. bf16 autocast in training: fp32 vs --amp on the bundled world, same seed.
if [ -n "$DATA" ]; then
  for m in fp32 amp; do
    amp=(); [ "$m" = amp ] && amp=(--amp)
    step "train_$m" "$CAP_TRAIN" 20 "$BIN" train --data "$DATA" --device "$DEV" --seed 0 \
      "${TRAIN_ARGS[@]}" "${amp[@]}" --out "$S/train_$m"
  done
  # 8. The real loader on prepared 800x350 data vs the training step (paper, batch 8).
  step bench_train "$CAP_BTRAIN" 20 "$BIN" bench train --data "$DATA" --device "$DEV" \
    "${BTRAIN_ARGS[@]}" --out "$S/bench_train.json"
else
  log "no prepared data (bundle/prepared): train and bench train skipped"
  printf 'train_fp32\tskipped\t0\tno data\ntrain_amp\tskipped\t0\tno data\nbench_train\tskipped\t0\tno data\n' >> "$STEPS"
fi
# 9. The CUDA demo plan (bigger world, wider network), with what is left.
step demo "$CAP_DEMO" 45 "$BIN" demo --out "$S/demo" --seed 7 --pictures 1 "${DEMO_ARGS[@]}"

# ------------------------------------------------------------------------------------------
# Consolidate (≤ 7 files) and print the table.
export GC_S="$S" GC_OUT="$OUTDIR" GC_DRY="$DRY" GC_GPU="$GPU_INFO" GC_CUDA="$CUDA_DRV" \
  GC_LDD="$LDD_CUDA" GC_BIN="$BIN" GC_BUNDLE="$BUNDLE_JSON" GC_T0="$T0" GC_BUDGET="$BUDGET" \
  GC_PRESETS="$PRESETS" GC_VARIANTS="$VARIANTS" GC_DEV="$DEV" GC_DEMO_EPOCHS="$DEMO_EPOCHS"
"$PY" - <<'PYEOF'
import glob, json, os, platform, socket, time
S, OUT = os.environ["GC_S"], os.environ["GC_OUT"]
dry = os.environ["GC_DRY"] == "1"


def load(p):
    try:
        with open(p) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def dump(name, obj):
    with open(os.path.join(OUT, name), "w") as f:
        json.dump(obj, f, indent=2)


steps = []
with open(os.path.join(S, "steps.tsv")) as f:
    for line in f:
        parts = line.rstrip("\n").split("\t")
        if len(parts) >= 3:
            steps.append({"step": parts[0], "status": parts[1], "seconds": int(parts[2]),
                          "command": parts[3] if len(parts) > 3 else ""})
status = {s["step"]: s["status"] for s in steps}
try:
    import torch
    torch_v, cuda_v = torch.__version__, torch.version.cuda
    cudnn_v = torch.backends.cudnn.version()
except Exception as e:  # noqa: BLE001
    torch_v, cuda_v, cudnn_v = f"not importable: {e}", None, None
env = {
    "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    "host": socket.gethostname(), "platform": platform.platform(), "cpus": os.cpu_count(),
    "dry_run": dry, "gpu": os.environ["GC_GPU"] or None,
    "nvidia_smi_cuda": os.environ["GC_CUDA"] or None,
    "torch": torch_v, "torch_cuda": cuda_v, "cudnn": cudnn_v,
    "ldd_libtorch_cuda": os.environ["GC_LDD"] or None, "binary": os.environ["GC_BIN"],
    "bundle": load(os.environ["GC_BUNDLE"]) if os.environ["GC_BUNDLE"] else None,
    "budget_s": int(os.environ["GC_BUDGET"]),
    "total_s": int(time.time()) - int(os.environ["GC_T0"]),
    "steps": steps,
}

ours = []
for p in sorted(glob.glob(os.path.join(S, "ours_*.json"))):
    r = load(p)
    if r:
        r["variant"] = os.path.basename(p)[len("ours_"):-5].split("_", 1)[1]
        ours.append(r)
torch_runs = []
for p in sorted(glob.glob(os.path.join(S, "torch_*.json"))):
    r = load(p)
    if r:
        torch_runs += r.get("runs", [r])
for r in torch_runs:  # the variant asked for (on the CPU both sides run fp32 NCHW instead)
    r["variant"] = r.get("variant_requested") or (
        r.get("precision", "?") + ("-cl" if r.get("channels_last") else ""))
dump("bench_ours.json", {"runs": ours, "status": {k: v for k, v in status.items()
                                                  if k.startswith("ours_")}})
dump("bench_torch.json", {"runs": torch_runs, "status": {k: v for k, v in status.items()
                                                         if k.startswith("torch_")}})


def med(r, phase):
    t = (r or {}).get(phase)
    return t.get("median_ms") if t else None


def find_torch(cfg, variant, mode):
    for r in torch_runs:
        if (r.get("config") == cfg and r.get("ordinal") == mode and r.get("variant") == variant
                and "error" not in r):
            return r
    return None


def ratio(a, b):
    return None if (a is None or b is None or b == 0) else a / b


rows = []
for r in ours:
    cfg = r["config"]
    # Matched on the variant asked for: on the CPU both sides run it as fp32 NCHW.
    v = r["variant"]
    for phase, label in [("forward", f"forward b{r['forward']['batch'] if r.get('forward') else '?'}"),
                         ("forward_decode", "fwd+decode"),
                         ("train_step", f"train b{r['train_step']['batch'] if r.get('train_step') else '?'}")]:
        row = {"config": cfg, "variant": v, "phase": phase, "label": label,
               "ours_ms": med(r, phase)}
        for mode in ("released", "efficient"):
            t = find_torch(cfg, v, mode)
            row[f"torch_{mode}_ms"] = med(t, phase)
            row[f"ratio_vs_{mode}"] = ratio(row["ours_ms"], row[f"torch_{mode}_ms"])
        rows.append(row)
mem = []
for r in ours:
    t = r.get("train_step") or {}
    tr = find_torch(r["config"], r["variant"], "released") or {}
    te = find_torch(r["config"], r["variant"], "efficient") or {}
    mem.append({
        "config": r["config"], "variant": r["variant"],
        "ours_train_gpu_mib_nvidia_smi": t.get("gpu_memory_mib"),
        "torch_released_train_gpu_mib_nvidia_smi": (tr.get("train_step") or {}).get("gpu_memory_mib"),
        "torch_released_train_peak_reserved_mib":
            ((tr.get("train_step") or {}).get("allocator") or {}).get("torch_peak_reserved_mib"),
        "torch_efficient_train_peak_reserved_mib":
            ((te.get("train_step") or {}).get("allocator") or {}).get("torch_peak_reserved_mib"),
    })
prec = [{"config": r["config"], "variant": r["variant"], "impl": "ours", **r["precision_check"]}
        for r in ours if r.get("precision_check")]
prec += [{"config": r["config"], "variant": r["variant"], "impl": f"torch-{r['ordinal']}",
          **r["precision_check"]} for r in torch_runs if r.get("precision_check")]

# Issue 45's checks after the science step.
science = load(os.path.join(OUT, "science.json"))
bf16_rec = load(os.path.join(S, "bf16_trained.json")) or {}
bf16_trained = bf16_rec.get("precision_check")  # null on the CPU: bf16 runs on CUDA only


def iter_losses(run):
    out = {}
    try:
        with open(os.path.join(S, run, "metrics.jsonl")) as fh:
            for line in fh:
                d = json.loads(line)
                if d.get("kind") == "iter":
                    out[d["iteration"]] = d["loss"]
    except (OSError, ValueError, KeyError):
        pass
    return out


single, rank = iter_losses("nccl_single"), iter_losses("nccl_rank")
common = sorted(set(single) & set(rank))
allreduce = None
try:
    with open(os.path.join(S, "nccl_rank.log")) as fh:
        allreduce = next((l.strip() for l in fh if l.startswith("all-reduce (")), None)
except OSError:
    pass
max_diff = max((abs(single[i] - rank[i]) for i in common), default=None)
nccl = {"status": {"single": status.get("nccl_single"), "rank": status.get("nccl_rank")},
        "iterations_compared": len(common), "max_abs_loss_difference": max_diff,
        "equal_within_1e-4": None if max_diff is None else max_diff <= 1e-4,
        "allreduce_line": allreduce,
        "backend": (allreduce.split("(")[1].split(",")[0] if allreduce else None)}
ort_cuda = load(os.path.join(S, "ort_cuda.json"))
# Every command's whole output (log.txt keeps only tails): the science runs' logs included.
deprecations = []
for root, _, files in os.walk(S):
    for name in sorted(files):
        if name.endswith(".log"):
            with open(os.path.join(root, name), errors="replace") as fh:
                deprecations += [f"{name}: {l.strip()}" for l in fh if "deprecat" in l.lower()]
inference = {}
for p in os.environ["GC_PRESETS"].split():
    r = load(os.path.join(S, f"infer_{p}.json")) or {}
    cl = load(os.path.join(S, f"infer_{p}_cl.json")) or {}
    inference[p] = {"graph": r.get("graph"), "forward_ms": med(r, "forward"),
                    "forward_decode_ms": med(r, "forward_decode"),
                    "forward_channels_last_ms": med(cl, "forward"),
                    "forward_decode_channels_last_ms": med(cl, "forward_decode"),
                    "channels_last_status": status.get(f"infer_{p}_cl"),
                    "forward_decode_cuda_graph_ms": med(r, "forward_decode_graph"),
                    "cuda_graph": r.get("cuda_graph"),
                    "cuda_graphs_built": r.get("cuda_graphs_built"),
                    "status": status.get(f"infer_{p}")}
def stats_line(name, marker):
    try:
        with open(os.path.join(S, f"{name}.log")) as fh:
            return next((l.strip() for l in fh if marker in l), None)
    except OSError:
        return None


pipeline = stats_line("predict_pipeline", " images in ")
pipeline_graph = stats_line("predict_graph", " images in ")
pipeline_tokens = stats_line("predict_tokens", " images in ")
pipeline_graph_how = stats_line("predict_graph", "cuda graph:")
prof = load(os.path.join(S, "profile_released.json")) or {}
for v in (prof.get("layouts") or {}).values():
    if "top" in v:
        v["top"] = v["top"][:12]
checks_inference = {"inference_graph": inference, "predict_pipeline": pipeline,
                    "predict_pipeline_status": status.get("predict_pipeline"),
                    "predict_cuda_graph": pipeline_graph,
                    "predict_cuda_graph_how": pipeline_graph_how,
                    "predict_cuda_graph_status": status.get("predict_graph"),
                    "predict_tokens": pipeline_tokens,
                    "predict_tokens_status": status.get("predict_tokens"),
                    "profile_train": prof or None,
                    "profile_status": status.get("profile_released")}
checks = {"bf16_trained": bf16_trained, "bf16_trained_status": status.get("bf16_trained"),
          "bf16_trained_weights": bf16_rec.get("weights"),
          "nccl": nccl, "ort_cuda": ort_cuda, "ort_cuda_status": status.get("ort_cuda"),
          "deprecation_lines": len(deprecations), "deprecation_examples": deprecations[:5],
          "inference_speed": checks_inference,
          "cuda_graphs": "bench model --cuda-graph rows in inference_speed.inference_graph"}

# Training fp32 vs amp.
train = {}
for m in ("fp32", "amp"):
    vals, ep, ep_own = [], [], []
    try:
        with open(os.path.join(S, f"train_{m}", "metrics.jsonl")) as f:
            for line in f:
                d = json.loads(line)
                if d.get("val"):
                    vals.append(d["val"]["rmse"])
                if d.get("kind") == "epoch":
                    ep.append(d.get("images_per_s"))
                    ep_own.append(d.get("epoch_images_per_s"))
    except OSError:
        pass
    train[m] = {"status": status.get(f"train_{m}"), "val_rmse": vals,
                "best_val_rmse": min(vals[1:] or vals or [None]) if vals else None,
                "images_per_s": ep, "epoch_images_per_s": ep_own}
bt = load(os.path.join(S, "bench_train.json"))
loader = None
if bt:
    loader = {k: bt.get(k) for k in ("preset", "batch_size", "frame", "amp",
                                     "train_images_per_s", "loader_images_per_s",
                                     "loader_threads", "train_step_seconds")}
    if bt.get("train_images_per_s"):
        loader["loader_over_step_rate"] = bt["loader_images_per_s"] / bt["train_images_per_s"]
dump("train.json", {"train": train, "bench_train": loader, "nccl": nccl,
                    "bench_train_status": status.get("bench_train"),
                    "note": "tiny preset on the bundled 10x5-keyframe world, same seed; "
                            "bench_train: loader alone vs step rate with the loader running"})

demo = load(os.path.join(S, "demo", "report", "summary.json"))
demo_out = {"status": status.get("demo"), "epochs_override": os.environ["GC_DEMO_EPOCHS"]}
if demo:
    s = demo.get("summary", {})
    demo_out.update({"rgb_rmse": s.get("rgb_rmse"), "fusion_rmse": s.get("fusion_rmse"),
                     "fusion_margin_m": (s["rgb_rmse"] - s["fusion_rmse"])
                     if s.get("rgb_rmse") is not None and s.get("fusion_rmse") is not None
                     else None,
                     "stage_seconds": s.get("stage_seconds"), "total_seconds":
                         s.get("total_seconds"), "preset": s.get("preset"),
                     "plan": demo.get("plan")})
else:
    stages = [d for d in ("world", "prepared", "rgb", "fusion", "report")
              if os.path.isdir(os.path.join(S, "demo", d))]
    demo_out["reached"] = stages
dump("demo.json", demo_out)

# Targets (issue 9): ours best variant vs the authors' form (torch ordinal=released, fp32 NCHW).
targets = []
if not dry:
    def best(cfg, phase):
        xs = [(med(r, phase), r["variant"]) for r in ours if r["config"] == cfg and med(r, phase)]
        return min(xs) if xs else (None, None)
    for cfg in ("released", "paper"):
        auth = find_torch(cfg, "fp32", "released")
        for phase, abs_t in (("forward", 5.0), ("train_step", 100.0)):
            b, v = best(cfg, phase)
            a = med(auth, phase)
            targets.append({"config": cfg, "phase": phase, "ours_best_ms": b, "variant": v,
                            "torch_released_fp32_ms": a, "ratio": ratio(b, a),
                            "target_ms": abs_t, "target_ratio": 0.5,
                            "met": None if b is None or a is None else
                            (b <= abs_t and b / a <= 0.5)})
        ms = [m["ours_train_gpu_mib_nvidia_smi"] for m in mem
              if m["config"] == cfg and m["ours_train_gpu_mib_nvidia_smi"]]
        targets.append({"config": cfg, "phase": "train_peak_gpu_mib",
                        "ours_min_over_variants_mib": min(ms) if ms else None,
                        "target_mib": 12 * 1024,
                        "met": (min(ms) <= 12 * 1024) if ms else None,
                        "note": "nvidia-smi process memory after the phase (peak reserved + "
                                "CUDA context), as bench model reports it"})

summary = {"env": {k: env[k] for k in ("date_utc", "gpu", "nvidia_smi_cuda", "torch", "dry_run",
                                        "total_s")},
           "timings": rows, "memory": mem, "precision_checks": prec,
           "train": {m: {"best_val_rmse": train[m]["best_val_rmse"],
                         "status": train[m]["status"]} for m in train},
           "loader": loader, "demo": demo_out, "targets": targets,
           "science": None if not science else {
               k: science.get(k) for k in ("ok", "training", "margin", "runs", "wall_seconds")},
           "checks": checks,
           "steps": {s["step"]: s["status"] for s in steps}}
dump("summary.json", summary)
dump("env.json", env)


def f(x, p=2):
    return "-" if x is None else (f"{x:.{p}f}" if isinstance(x, float) else str(x))


lines = []
lines.append(f"gpu-check {env['date_utc']} on {env['gpu'] or 'CPU (dry run)' if dry else env['gpu']}"
             f" {env['nvidia_smi_cuda'] or ''}, torch {env['torch']}, {env['total_s']} s")
lines.append("")
lines.append(f"{'config':<9} {'variant':<8} {'phase':<11} {'ours ms':>9} {'PT-rel ms':>10} "
             f"{'ours/rel':>8} {'PT-eff ms':>10} {'ours/eff':>8}")
for r in rows:
    lines.append(f"{r['config']:<9} {r['variant']:<8} {r['label']:<11} {f(r['ours_ms']):>9} "
                 f"{f(r['torch_released_ms']):>10} {f(r['ratio_vs_released'], 3):>8} "
                 f"{f(r['torch_efficient_ms']):>10} {f(r['ratio_vs_efficient'], 3):>8}")
lines.append("(PT-rel = PyTorch eager, the released code's ordinal layer and loss; PT-eff = "
             "PyTorch eager, our efficient ordinal form)")
if any(m["ours_train_gpu_mib_nvidia_smi"] for m in mem):
    lines.append("")
    lines.append(f"{'config':<9} {'variant':<8} {'train MiB ours':>15} {'PT-rel':>8} "
                 f"{'PT-rel peak':>12} {'PT-eff peak':>12}")
    for m in mem:
        lines.append(f"{m['config']:<9} {m['variant']:<8} "
                     f"{f(m['ours_train_gpu_mib_nvidia_smi']):>15} "
                     f"{f(m['torch_released_train_gpu_mib_nvidia_smi']):>8} "
                     f"{f(m['torch_released_train_peak_reserved_mib'], 0):>12} "
                     f"{f(m['torch_efficient_train_peak_reserved_mib'], 0):>12}")
for p in prec:
    lines.append(f"precision {p['impl']:<16} {p['config']:<9} {p['variant']:<8} "
                 f">1 bin: {100 * p['frac_pixels_level_moved_gt_1']:.4f} % "
                 f"(any: {100 * p['frac_pixels_level_moved']:.3f} %) "
                 f"{'ok' if p['ok'] else 'FAIL'} (≤ 0.1 %)")
for m in ("fp32", "amp"):
    t = train[m]
    lines.append(f"train {m:<4}: val RMSE {' → '.join(f(x) for x in t['val_rmse'][:1] + t['val_rmse'][-1:])}"
                 f" (best {f(t['best_val_rmse'])}) [{t['status']}]")
if loader:
    lines.append(f"loader: {f(loader.get('loader_images_per_s'), 1)} img/s vs training "
                 f"{f(loader.get('train_images_per_s'), 1)} img/s "
                 f"(ratio {f(loader.get('loader_over_step_rate'))}; ≥ 1 = never starves)")
if demo:
    lines.append(f"demo: RGB {f(demo_out['rgb_rmse'], 3)} m, fusion {f(demo_out['fusion_rmse'], 3)} m, "
                 f"margin {f(demo_out['fusion_margin_m'], 3)} m in {f(demo_out['total_seconds'], 1)} s "
                 f"[{demo_out['status']}]")
else:
    lines.append(f"demo: {demo_out['status']}, reached {demo_out.get('reached')}")
for t in targets:
    lines.append("target " + json.dumps(t))
if science:
    mg = science.get("margin") or {}
    mm = (mg.get("margin_m") or {}).get("mean")
    lines.append(f"science: N = {science['training'].get('train_samples')}, "
                 f"{science['training'].get('iterations')} iterations per run, margin of late-sam "
                 f"over rgb {f(mm, 3)} m, t = {f(mg.get('t'))}, finding: {mg.get('finding')} "
                 f"[{status.get('science')}]")
else:
    lines.append(f"science: no science.json [{status.get('science')}]")
if bf16_trained:
    lines.append(f"bf16 on the trained checkpoint: >1 bin {100 * bf16_trained['frac_pixels_level_moved_gt_1']:.4f} % "
                 f"({'ok' if bf16_trained['ok'] else 'FAIL'}, ≤ 0.1 %)")
else:
    lines.append(f"bf16 on the trained checkpoint: not measured [{status.get('bf16_trained')}]")
lines.append(f"one rank ({nccl['backend'] or '?'}) vs one process: {nccl['iterations_compared']} "
             f"iterations, max |Δloss| {f(nccl['max_abs_loss_difference'], 6)}; {nccl['allreduce_line'] or 'no all-reduce line'}")
if ort_cuda:
    lines.append(f"onnxruntime ({(ort_cuda.get('providers_used') or ['-'])[0]}): "
                 f"{f(ort_cuda.get('median_ms'))} ms median, batch {ort_cuda.get('batch')}"
                 f"{'; ' + ort_cuda['note'] if ort_cuda.get('note') else ''}")
else:
    lines.append(f"onnxruntime: not measured [{status.get('ort_cuda')}]")
lines.append(f"libtorch deprecation lines in the log: {checks['deprecation_lines']}")
for p, r in inference.items():
    lines.append(f"inference graph {p}: forward {f(r['forward_ms'])} ms, with decode "
                 f"{f(r['forward_decode_ms'])} ms, from a CUDA graph "
                 f"{f(r['forward_decode_cuda_graph_ms'])} ms ({r['cuda_graph']}) [{r['status']}]")
lines.append(f"predict pipeline: {pipeline or 'not measured'} [{status.get('predict_pipeline')}]")
lines.append(f"predict --cuda-graph: {pipeline_graph or 'not measured'} ({pipeline_graph_how}) "
             f"[{status.get('predict_graph')}]")
bad = [s for s in steps if s["status"] not in ("ok", "not selected")]
lines.append("steps not ok: " + (", ".join(f"{s['step']} ({s['status']})" for s in bad) or "none"))
lines.append(f"results: {OUT}")
text = "\n".join(lines)
print(text)
with open(os.path.join(OUT, "log.txt"), "a") as fh:
    fh.write("\n" + text + "\n")
PYEOF
PRC=$?
# log.txt stays bounded.
if [ "$(stat -c %s "$LOG")" -gt 1000000 ]; then tail -c 1000000 "$LOG" > "$S/log.tail" && mv "$S/log.tail" "$LOG"; fi
rm -rf "$S"
exit $PRC

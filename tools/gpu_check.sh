#!/usr/bin/env bash
# The checks to run whenever a CUDA GPU is at hand (nothing in the tests or CI needs one):
#   bash tools/gpu_check.sh [OUT]          (OUT: default runs/gpu_check/)
#   1. the CUDA tests: pytest -m gpu
#   2. a few hundred training steps of experiment=samp_paper on the GPU, through the real recipe (DataModule,
#      Lightning), printing the step rate and torch's peak GPU memory. Data: the `paper` dataset when one is built
#      (under $SAMP_DATASETS_DIR, else datasets/); else a shrunk `paper` spec generated into OUT/datasets, named
#      gpu_check: all 40 scenes of the spec (32 train, so batches span as many scenes as the paper's do), 4
#      demonstrations per scene, grids at n_e = 160 only. Robot SDF: the newest robot_sdf_panda_paper run (under
#      $SAMP_RUNS_DIR, else runs/) when there is one; else one trained here at the paper's size on a few thousand
#      samples per link for GPU_CHECK_SDF_STEPS steps (accuracy does not matter for timing). Its runs go to OUT/runs.
#   3. the policy step at n_e = 160 at B = 1 and B = 100 (tools/bench.py policy --device cuda --anchors 40 160:
#      the quickstart network at 40, the paper-width one at 160), with the robot SDF of step 2
#   4. tools/bench.py paper --device cuda: the paper-scale training step at B = 50 (22 of 32 scenes per batch for
#      samp_paper) and the expected wall time of the whole run from it
# Each step's output is in OUT/*.txt (bench reports in OUT/*.json); a summary in OUT/summary.txt. A step that fails
# is reported and the others still run; the exit status is 1 if any failed. Without a GPU it exits 3 at once.
# Sizes: GPU_CHECK_STEPS (300 training steps), GPU_CHECK_SDF_STEPS (300), GPU_CHECK_WORKERS (planning processes).
set -uo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  if [ -x "$REPO/.venv/bin/python" ]; then PY="$REPO/.venv/bin/python"; else PY="python3"; fi
fi

refuse() {
  echo "gpu_check: no GPU here: $1. Nothing was run; run this on a machine with a CUDA GPU." >&2
  exit 3
}
command -v nvidia-smi >/dev/null 2>&1 || refuse "nvidia-smi is not on the PATH"
nvidia-smi -L >/dev/null 2>&1 || refuse "nvidia-smi finds no device"
"$PY" -c "import sys, torch; sys.exit(0 if torch.cuda.is_available() else 1)" 2>/dev/null \
  || refuse "torch.cuda.is_available() is false (CUDA_VISIBLE_DEVICES='${CUDA_VISIBLE_DEVICES-}')"

OUT="${1:-runs/gpu_check}"
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
STEPS="${GPU_CHECK_STEPS:-300}"
SDF_STEPS="${GPU_CHECK_SDF_STEPS:-300}"
WORKERS="${GPU_CHECK_WORKERS:-$(nproc)}"
DATASETS="${SAMP_DATASETS_DIR:-$REPO/datasets}"
RUNS="${SAMP_RUNS_DIR:-$REPO/runs}"
export PYTHONPATH="$REPO${PYTHONPATH:+:$PYTHONPATH}" RERUN_ANALYTICS=0
cd "$REPO"

SUMMARY="$OUT/summary.txt"
: > "$SUMMARY"
FAILED=0
say() { echo "$*" | tee -a "$SUMMARY"; }
step() {  # step NAME COMMAND...: run it, its output to OUT/NAME.txt, one line in the summary
  local name="$1"; shift
  echo "== $name: $*" >&2
  local t0=$SECONDS
  if "$@" > "$OUT/$name.txt" 2>&1; then
    say "ok      $name ($((SECONDS - t0)) s)"
  else
    say "FAILED  $name ($((SECONDS - t0)) s, exit $?): see $OUT/$name.txt"; FAILED=1
  fi
}

nvidia-smi > "$OUT/nvidia-smi.txt" 2>&1
say "gpu_check $(date -u +%FT%TZ) on $(nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | head -1)"
COMMIT="$(git rev-parse --short HEAD 2>/dev/null || echo unknown)"
git diff --quiet 2>/dev/null || COMMIT="$COMMIT (with uncommitted changes)"
say "commit $COMMIT"

# 1. CUDA tests
step pytest_gpu "$PY" -m pytest -m gpu -q -p no:cacheprovider tests

# 2. samp_paper on the GPU
if ls "$DATASETS"/paper/*/manifest.json >/dev/null 2>&1; then
  DATA_ROOT="$DATASETS"; DATA=paper
  say "data: the paper dataset in $DATASETS"
else
  DATA_ROOT="$OUT/datasets"; DATA=gpu_check
  say "data: no paper dataset in $DATASETS; a shrunk paper spec (gpu_check: 40 scenes, 4 demonstrations each, n_e 160)"
  step data "$PY" -m samp.data generate dataset=paper dataset.name=gpu_check dataset.trajectories_per_scene=4 \
    dataset.eval_problems_per_scene=1 "dataset.resolutions=[160]" workers="$WORKERS" root="$DATA_ROOT" progress=false
fi
SDF="$(ls -d "$RUNS"/robot_sdf_panda_paper/*/robot_sdf.pt 2>/dev/null | tail -1)"
if [ -n "$SDF" ]; then
  say "robot SDF: $SDF"
else
  say "robot SDF: none trained at the paper's size in $RUNS; a shrunk one ($SDF_STEPS steps, tiny samples) in $OUT/runs"
  step robot_sdf env SAMP_RUNS_DIR="$OUT/runs" SAMP_DATASETS_DIR="$OUT/datasets" "$PY" -m samp.train \
    experiment=robot_sdf_panda_paper trainer=gpu robot_sdf_samples=tiny trainer.max_steps="$SDF_STEPS" '~robot_sdf_eval'
  SDF="$(ls -d "$OUT"/runs/robot_sdf_panda_paper/*/robot_sdf.pt 2>/dev/null | tail -1)"
fi
step train_samp_paper "$PY" - "$STEPS" "$DATA" "$DATA_ROOT" "${SDF:-robot_sdf_panda_paper}" "$OUT/runs" <<'EOF'
# A few hundred steps of samp_paper through the training recipe; the step rate from the intervals between training
# batches after the first 20 (data loading included, validation off), and torch's peak GPU memory.
import sys
import time

import pytorch_lightning as pl
import torch

steps, data, root, sdf, runs = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5]


class StepRate(pl.Callback):
    def __init__(self, skip: int = 20):
        self.skip, self.times, self.last = skip, [], None

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
        if module.device.type == "cuda":
            torch.cuda.synchronize(module.device)
        now = time.perf_counter()
        if self.last is not None and batch_idx > 0 and trainer.global_step > self.skip:
            self.times.append(now - self.last)  # within an epoch: no epoch boundary in it
        self.last = now

    def on_train_end(self, trainer, module):
        rate = len(self.times) / sum(self.times) if self.times else float("nan")
        dev, cuda = module.device, module.device.type == "cuda"
        memory = (f"peak GPU memory {torch.cuda.max_memory_allocated(dev) / 2**30:.2f} GiB allocated, "
                  f"{torch.cuda.max_memory_reserved(dev) / 2**30:.2f} GiB reserved" if cuda else "no GPU memory (CPU)")
        print(f"samp_paper on {torch.cuda.get_device_name(dev) if cuda else 'the CPU'}: {trainer.global_step} steps; "
              f"{rate:.2f} steps/s ({1e3 / rate:.1f} ms/step, B = {trainer.datamodule.batch_size}) over "
              f"{len(self.times)} steps after the first {self.skip}; {memory}; at 31,360 steps per epoch (the paper "
              f"spec) {31360 / rate / 3600:.2f} h per epoch, {160 * 31360 / rate / 3600:.1f} h for 160 epochs",
              flush=True)


from samp.train.recipe import train  # noqa: E402

train(["experiment=samp_paper", "trainer=gpu", f"datamodule.dataset={data}", f"system.robot_sdf={sdf}",
       f"trainer.max_steps={steps}", "trainer.max_epochs=100", "+trainer.limit_val_batches=0", "callbacks=default",
       "evaluation.problems=0", "evaluation.benchmark=null", "+callbacks.step_rate._target_=__main__.StepRate"],
      paths={"runs_dir": runs, "datasets_dir": root})
EOF
grep -h "steps/s" "$OUT/train_samp_paper.txt" | tee -a "$SUMMARY"

# 3. the policy step at n_e = 160, B = 1 and B = 100
step bench_policy "$PY" tools/bench.py policy --device cuda --anchors 40 160 ${SDF:+--robot-sdf "$SDF"} \
  --out "$OUT/bench_policy.json"
grep -h -E "n_e=160: step B=1|step B=100" "$OUT/bench_policy.txt" | tee -a "$SUMMARY"

# 4. the paper-scale training step and the expected wall time from it
step bench_paper "$PY" tools/bench.py paper --device cuda --steps 20 --disk-max-n-e 70 ${SDF:+--robot-sdf "$SDF"} \
  --out "$OUT/bench_paper.json"
grep -h -E "training step|expected training|paper's GPU|memory of one" "$OUT/bench_paper.txt" | tee -a "$SUMMARY"

say "outputs in $OUT"
exit "$FAILED"

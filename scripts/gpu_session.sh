#!/usr/bin/env bash
# Ten minutes on a GPU, one command (docs/performance.md, "GPU session"). Run from the
# repository root on a GPU machine with no internet and no system packages to install:
#   1. installs the wheels and GL libraries carried in .whl/ and .gl/ (scripts/gpu_bundle.sh
#      makes both here; without them the machine's own packages are used);
#   2. finds out whether MuJoCo renders there through the NVIDIA driver's EGL;
#   3. renders a training set on every core if it does, else uses the carried data/gpu;
#   4. runs benchmarks/training.py on CUDA (paper size; batch 10 and 256; eager, compiled,
#      graphed);
#   5. trains the paper-size VRNN-LRU with configs/paper_fast.yaml on that set,
#      clips held on the GPU, VOE statistics of the validation probes every VAL_EVERY steps;
#   6. tests the last checkpoint on the test probes and draws the curves.
# Everything lands in $OUT (default gpu_out/): session.log, benchmark.txt/.json, the fit and
# test logs, curves.png, report.tgz (the test report) and runs.tgz (TensorBoard events, no
# checkpoints). BUDGET (seconds, default 540) bounds the whole script: the fit gets what the
# steps before it left, less what the test needs. SMOKE=1 runs every step at a tiny size on
# any machine (a CPU), to check the plumbing before a GPU is spent on it.
#   bash scripts/gpu_session.sh
set -u
OUT=${OUT:-gpu_out}
BUDGET=${BUDGET:-540}
SMOKE=${SMOKE:-0}
VAL_EVERY=${VAL_EVERY:-$([ "$SMOKE" = 1 ] && echo 10 || echo 250)}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 MUJOCO_GL=egl PROTOCOL_BUFFERS_PYTHON_IMPLEMENTATION=python
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}  # the package is not installed there
START=$(date +%s)
elapsed() { echo $(($(date +%s) - START)); }
log() { echo "== $(elapsed) s: $*" | tee -a "$OUT/session.log"; }

# --- 1. packages --------------------------------------------------------------------------------
if compgen -G ".whl/*.whl" >/dev/null; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PYTHONPATH
fi
if compgen -G ".gl/*.deb" >/dev/null; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
{
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>&1
    lscpu | grep -m1 "Model name"
    python3 -c "import torch, lightning, tensordict, mujoco; print('torch', torch.__version__, \
'lightning', lightning.__version__, 'tensordict', tensordict.__version__, 'mujoco', \
mujoco.__version__, 'cuda', torch.cuda.is_available())"
} 2>&1 | tee -a "$OUT/session.log"
if [ "$SMOKE" = 1 ]; then
    DEVICE=cpu; WORKERS=2; TRAIN=8; VAL=2; TEST=4; BATCHES=(8); MODELS=quickstart
    SIZES=(--model.init_args.latent_size 32 --model.init_args.mlp_sizes '[128, 128]'
           --model.init_args.memory_slot_size 32 --model.init_args.controller_size 64
           --model.init_args.encoder_blocks 4 --model.init_args.encoder_channels '[16, 16, 32]'
           --model.init_args.encoder_mlp_size 128 --model.init_args.compile off
           --data.init_args.batch_size 8)
else
    DEVICE=cuda; WORKERS=$(($(nproc) - 1)); TRAIN=2000; VAL=64; TEST=200; BATCHES=(10 256)
    MODELS=paper; SIZES=()
fi

# --- 2. rendering -------------------------------------------------------------------------------
RENDER_CHECK='import mujoco, numpy
model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><light pos=\"0 0 3\"/><geom type=\"sphere\" size=\".2\" rgba=\"1 0 0 1\"/></worldbody></mujoco>")
with mujoco.Renderer(model, 64, 64) as renderer:
    data = mujoco.MjData(model); mujoco.mj_forward(model, data); renderer.update_scene(data)
    print("rendered, mean pixel", float(renderer.render().mean()))'
NVIDIA_EGL=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
if timeout 60 python3 -c "$RENDER_CHECK" >>"$OUT/session.log" 2>&1; then
    RENDER=1
elif [ -f "$NVIDIA_EGL" ] && __EGL_VENDOR_LIBRARY_FILENAMES=$NVIDIA_EGL timeout 60 \
        python3 -c "$RENDER_CHECK" >>"$OUT/session.log" 2>&1; then
    export __EGL_VENDOR_LIBRARY_FILENAMES=$NVIDIA_EGL
    RENDER=1
else
    RENDER=0
fi
log "MuJoCo renders here through EGL: $RENDER"

# --- 3. data ------------------------------------------------------------------------------------
if [ "$RENDER" = 1 ]; then
    DATA=data/gpu_session
    log "rendering $TRAIN examples + $TRAIN controls per concept, $VAL / $TEST probe pairs per variant"
    timeout 150 python3 -m voe_lightning generate --root "$DATA" --train_examples "$TRAIN" \
        --val_pairs "$VAL" --test_pairs "$TEST" --generalization_pairs "$VAL" \
        --workers "$WORKERS" --progress false 2>&1 | tail -n 3 | tee -a "$OUT/session.log"
else
    DATA=data/gpu; TRAIN=200; VAL=24; TEST=48  # what scripts/gpu_bundle.sh renders and carries
    [ -f "$DATA/manifest.json" ] || { log "no data at $DATA: carry it (scripts/gpu_bundle.sh)"; exit 1; }
fi
DATA_ARGS=(--data.init_args.root "$DATA" --data.init_args.train_examples "$TRAIN"
           --data.init_args.val_pairs "$VAL" --data.init_args.test_pairs "$TEST"
           --data.init_args.generalization_pairs "$VAL" --data.init_args.train_on_device true
           --data.init_args.num_workers 4)

# --- 4. benchmark -------------------------------------------------------------------------------
log "benchmark"
timeout 200 python3 benchmarks/training.py --device "$DEVICE" --models "$MODELS" \
    --batch-size "${BATCHES[@]}" --paths eager compiled $([ "$DEVICE" = cuda ] && echo graphed) \
    --rounds 2 --steps "$([ "$SMOKE" = 1 ] && echo 2 || echo 20)" --json "$OUT/benchmark.json" \
    >"$OUT/benchmark.txt" 2>&1
tail -n 12 "$OUT/benchmark.txt" | tee -a "$OUT/session.log"

# --- 5. fit -------------------------------------------------------------------------------------
FIT_SECONDS=$((BUDGET - $(elapsed) - 75))
[ "$FIT_SECONDS" -ge 60 ] || FIT_SECONDS=60  # the steps before ran long: still train a minute
RUN=(--config configs/paper_fast.yaml "${SIZES[@]}"
     "${DATA_ARGS[@]}" --trainer.logger.init_args.name gpu_session)
log "fit for ${FIT_SECONDS} s"
timeout $((FIT_SECONDS + 30)) python3 -m voe_lightning fit "${RUN[@]}" \
    --trainer.max_time "00:00:$((FIT_SECONDS / 60)):$((FIT_SECONDS % 60))" \
    --trainer.val_check_interval "$VAL_EVERY" >"$OUT/fit.log" 2>&1
tail -n 25 "$OUT/fit.log" | tee -a "$OUT/session.log"

# --- 6. test and curves -------------------------------------------------------------------------
RUN_DIR=$(ls -d runs/gpu_session/version_* 2>/dev/null | sort -V | tail -n 1)
log "test $RUN_DIR"
timeout 60 python3 -m voe_lightning test "${RUN[@]}" --ckpt_path last >"$OUT/test.log" 2>&1
tail -n 25 "$OUT/test.log" | tee -a "$OUT/session.log"
python3 -m voe_lightning analyze curves --runs "[\"paper-size VRNN-LRU=$RUN_DIR\"]" \
    --out "$OUT/curves.png" >>"$OUT/session.log" 2>&1
[ -d "$RUN_DIR/voe_report" ] && tar czf "$OUT/report.tgz" -C "$RUN_DIR" voe_report
tar czf "$OUT/runs.tgz" --exclude='*.ckpt' --exclude=voe_report runs/gpu_session
log "done"
ls -la "$OUT" | tee -a "$OUT/session.log"

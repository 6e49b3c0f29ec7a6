#!/usr/bin/env bash
# One short GPU lease (issue 24, part 5), everything in one command so a lent machine's minutes
# go to measuring: (1) benchmarks/training.py on CUDA, bf16 without torch.compile, the configs'
# batches and a batch of 64; (2) the paper-size VRNN-LRU (configs/joint.yaml) and the
# visibility-aware object-centric model (configs/object_centric.yaml, surprise: likelihood),
# side by side on the one GPU for FIT_TIME (4 min) each on a small data set, with VOE statistics
# every 500 steps; (3) `test` of both on 48 pairs per variant. Results under
# $OUT (default gpu_out/): benchmark tables, logs, and runs.tgz (TensorBoard events and reports,
# no checkpoints). BENCHMARK=0 skips (1). Needs data/gpu (55 MB with the code and wheels, under a
# lease's 64 MiB): python -m voe_lightning generate --root data/gpu --train_examples 200
#   --val_pairs 24 --test_pairs 48 --generalization_pairs 24
# and, on a machine with no package index, the project's missing wheels in .whl/
# (docs/performance.md says which).
#   bash docs/study/scripts/gpu_lease.sh
set -u
OUT=${OUT:-gpu_out}
FIT_TIME=${FIT_TIME:-00:00:04:00}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 MUJOCO_GL=egl PROTOCOL_BUFFERS_PYTHON_IMPLEMENTATION=python
if compgen -G ".whl/*.whl" >/dev/null; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target /tmp/site .whl/*.whl
    export PYTHONPATH=/tmp/site:$PWD
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import torch, tensordict, torchrl, lightning; print('torch', torch.__version__, \
'tensordict', tensordict.__version__, 'torchrl', torchrl.__version__, 'lightning', \
lightning.__version__, torch.cuda.get_device_name())"
lscpu | grep -m1 "Model name"

if [ "${BENCHMARK:-1}" = 1 ]; then
echo "== benchmark: configs' batches"
timeout 120 python3 benchmarks/training.py --device cuda --compile off --rounds 3 \
    2>&1 | tee "$OUT/benchmark.txt" | tail -12
echo "== benchmark: batch 64"
timeout 80 python3 benchmarks/training.py --device cuda --compile off --rounds 3 \
    --batch-size 64 2>&1 | tee "$OUT/benchmark_b64.txt" | tail -8
fi
python3 -c "import mujoco; print('mujoco', mujoco.__version__)"

DATA=(--data.init_args.root data/gpu --data.init_args.train_examples 200
      --data.init_args.val_pairs 24 --data.init_args.test_pairs 48
      --data.init_args.generalization_pairs 24 --data.init_args.num_workers 3)
RUN=(--trainer.max_time "$FIT_TIME" --trainer.val_check_interval 500)
JOINT=(--config configs/joint.yaml "${DATA[@]}" --trainer.logger.init_args.name gpu_joint)
OBJECTS=(--config configs/object_centric.yaml "${DATA[@]}" --model.init_args.surprise likelihood
         --model.init_args.perception_steps 1500 --trainer.max_steps 200000
         --trainer.logger.init_args.name gpu_object_centric)
echo "== fit, side by side, $FIT_TIME each"
OMP_NUM_THREADS=4 python3 -m voe_lightning fit "${JOINT[@]}" "${RUN[@]}" >"$OUT/fit_joint.log" 2>&1 &
OMP_NUM_THREADS=4 python3 -m voe_lightning fit "${OBJECTS[@]}" "${RUN[@]}" \
    >"$OUT/fit_object_centric.log" 2>&1 &
wait
tail -n 3 "$OUT/fit_joint.log" "$OUT/fit_object_centric.log"
echo "== test"
OMP_NUM_THREADS=4 timeout 100 python3 -m voe_lightning test "${JOINT[@]}" \
    --ckpt_path last >"$OUT/test_joint.log" 2>&1 &
OMP_NUM_THREADS=4 timeout 100 python3 -m voe_lightning test "${OBJECTS[@]}" \
    --ckpt_path last \
    >"$OUT/test_object_centric.log" 2>&1 &
wait
tail -n 4 "$OUT/test_joint.log" "$OUT/test_object_centric.log"
tar czf "$OUT/runs.tgz" --exclude='*.ckpt' runs/gpu_joint runs/gpu_object_centric
ls -la "$OUT"

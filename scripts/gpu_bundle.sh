#!/usr/bin/env bash
# Make here what scripts/gpu_session.sh carries to a GPU machine that reaches no package index:
#   .whl/      wheels for its Python (3.12) of the packages its image lacks (the image has torch
#              2.11, lightning, torchmetrics, scipy, matplotlib, tensorboard, tqdm, rich, ...);
#   .gl/       the glvnd EGL/OpenGL loaders (Debian packages) through which MuJoCo reaches the
#              NVIDIA driver's EGL, in case the image lacks them;
#   data/gpu/  a small rendered store (200 + 200 clips per concept, 24 / 48 probe pairs per
#              variant), used only where MuJoCo cannot render on the GPU machine.
# All three are git-ignored and together stay under the 64 MiB a call carries. Then run
#   bash scripts/gpu_session.sh    (carrying .whl, .gl and data/gpu)
set -euo pipefail
cd "$(dirname "$0")/.."
PLATFORMS=()
for n in 17 27 28 31 34 35; do PLATFORMS+=(--platform "manylinux_2_${n}_x86_64"); done
PLATFORMS+=(--platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform any)
# Pinned to what ran beside the image's torch 2.11 (2026-11-26); mujoco as installed here.
MUJOCO=$(python3 -c "import mujoco; print(mujoco.__version__)")
WHEELS=(tensordict==0.12.0 torchrl==0.12.0 pyvers importlib_metadata orjson cloudpickle
        jsonargparse docstring-parser typeshed-client tfrecord crc32c zstandard pyopengl
        "mujoco==$MUJOCO" "mujoco-core==$MUJOCO")
rm -rf .whl && mkdir -p .whl
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
    --implementation cp "${PLATFORMS[@]}" -d .whl "${WHEELS[@]}"

rm -rf .gl /tmp/amd64 && mkdir -p .gl /tmp/amd64/partial
APT=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
apt-get "${APT[@]}" update -qq
(cd .gl && apt-get "${APT[@]}" download -qq libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)

MUJOCO_GL=egl python3 -m voe_lightning generate --root data/gpu --train_examples 200 \
    --val_pairs 24 --test_pairs 48 --generalization_pairs 24 --progress false
du -sh .whl .gl data/gpu

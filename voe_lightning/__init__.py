"""voe_lightning: probe a learned video model's intuitive physics with violation of expectation."""

import os

# Headless rendering: must be set before anything (torchrl included) imports mujoco.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"

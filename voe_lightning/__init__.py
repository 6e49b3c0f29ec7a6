"""voe_lightning: probe a learned video model's intuitive physics with violation of expectation."""

import os

# Headless rendering: must be set before anything (torchrl included) imports mujoco.
os.environ.setdefault("MUJOCO_GL", "egl")

from voe_lightning import old_paths  # noqa: E402

old_paths.install()  # voe_lightning.statistics & co., the paths before the sub-packages

__version__ = "0.1.0"

"""Shared test settings: headless rendering and small, fixed-seed sizes."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

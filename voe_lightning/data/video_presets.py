"""Named video settings for ``generate --preset``: the frames, frame rate and size that the
field's official surprise harnesses window (docs/benchmarks.md, "Probes at a harness's
lengths"). Every preset keeps the paper's 3 s clip, so every concept's scenes move as they do
in the paper's 15 frames, in seconds; only the sampling of time and space changes."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

from voe_lightning import specs
from voe_lightning.scenes.camera import PAPER_DURATION, VideoOptions


@dataclass(frozen=True)
class VideoPreset:
    """``num_frames`` frames of ``height`` x ``width`` at ``fps`` frames per second, for the
    ``harness`` named, whose config reads ``settings``."""

    num_frames: int
    fps: float
    height: int
    width: int
    harness: str
    settings: str

    def video(self) -> VideoOptions:
        return VideoOptions.at_fps(self.fps, self.num_frames, self.height, self.width)


#: The names ``generate --preset`` takes (``PRESETS``' keys).
PresetName = Literal["paper", "intphys", "intphys2_vjepa", "intphys2_vjepa2"]

PRESETS: dict[str, VideoPreset] = {
    # The package's own: the paper's 15 frames of 64 x 64 over 3 s (generate's defaults).
    "paper": VideoPreset(
        specs.NUM_FRAMES, specs.NUM_FRAMES / PAPER_DURATION, specs.HEIGHT, specs.WIDTH,
        "voe_lightning's own models (the paper's clips)", "the defaults",
    ),
    # IntPhys dev movies are 100 frames of 288 x 288; facebookresearch/jepa-intuitive-physics'
    # eval.py takes 99 // frame_step frames of each (frame_steps 2, 16-frame windows, stride 2).
    "intphys": VideoPreset(
        100, 100 / PAPER_DURATION, 288, 288,
        "jepa-intuitive-physics eval.py on IntPhys (dev movies: 100 frames of 288 x 288)",
        "dataset: intphys, frame_steps: 2, frames_per_clip: 16 (its shipped intphys configs)",
    ),
    # facebookresearch/IntPhys2's V-JEPA (1) config: 16-frame windows of every 10th frame at
    # 224: 151 frames or more fill one; 160 give 16 frames 3/16 s apart.
    "intphys2_vjepa": VideoPreset(
        160, 160 / PAPER_DURATION, 224, 224,
        "IntPhys2 prediction_evals, configs/vjepa_rope.yaml (V-JEPA)",
        "frames_per_clip: 16, frame_steps: 10, resolution: 224, context_lengths: [4..14]",
    ),
    # facebookresearch/IntPhys2's V-JEPA 2 config: 48-frame windows of every 10th frame at
    # 256: 471 frames or more fill one; 480 give 48 frames 1/16 s apart.
    "intphys2_vjepa2": VideoPreset(
        480, 480 / PAPER_DURATION, 256, 256,
        "IntPhys2 prediction_evals, configs/vjepa_2.yaml (V-JEPA 2)",
        "frames_per_clip: 48, frame_steps: 10, resolution: 256, context_lengths: [12..42]",
    ),
}  # fmt: skip
assert tuple(PRESETS) == get_args(PresetName)


def check_preset(name: object) -> VideoPreset:
    """The preset called ``name``; a ValueError names it and the valid ones."""
    if not isinstance(name, str) or name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; valid presets are: {', '.join(PRESETS)}")
    return PRESETS[name]

"""The positive control's constructor arguments: those a checkpoint must agree on
(``ARCHITECTURE``) and the checks that refuse the ones that make no model."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from voe_lightning.model import optimization

#: Constructor arguments that shape the parameters, or the priors they were trained with: a
#: checkpoint must agree on all of them.
ARCHITECTURE = (
    "perception",
    "hidden_size",
    "message_size",
    "use_camera",
    "components",
    "landing_component",
    "pivot_landing",
    "landing_change",
    "sight_lines",
    "floor",
    "inertia",
    "projection",
    "visibility_from",
    "code_size",
    "frame_size",
)
#: What the learner perceives of each object (``perception``): its 3D state, what its mask and
#: the frames show, that with what the depth image shows of it, or a learned code of its pixels.
PERCEPTIONS = ("states", "masks", "rgbd", "pixels")
#: What the learned p(seen) reads (``visibility_from``): memory, or the predicted states alone.
VISIBILITIES = ("memory", "states")
#: The arguments that give geometry or a prior about a 3D state, each with its value off
#: (``projection`` is not one: perceived by masks or rgbd, the image box is what is seen).
GEOMETRY_OFF = {
    "landing_component": False,
    "pivot_landing": False,
    "sight_lines": False,
    "floor": False,
}


def check_arguments(h: Mapping[str, Any]) -> None:
    """Refuse constructor arguments that make no model, naming the value and what is valid."""
    _check_perception(h)
    _check_sizes(h)
    _check_mixture(h)
    _check_withholding(h)
    optimization.check_schedule(h["lr_schedule"])


def _check_perception(h: Mapping[str, Any]) -> None:
    """Refuse a perception not in ``PERCEPTIONS``, and 3D geometry or priors without 3D states."""
    if h["perception"] not in PERCEPTIONS:
        raise ValueError(f"perception must be one of {PERCEPTIONS}, got {h['perception']!r}")
    if h["visibility_from"] not in VISIBILITIES:
        raise ValueError(
            f"visibility_from must be one of {VISIBILITIES}, got {h['visibility_from']!r}"
        )
    if h["visibility_from"] == "states" and h["sight_lines"]:
        raise ValueError(
            "visibility_from: states learns what is seen from the states alone, with no sight "
            "lines to add to; set sight_lines: false"
        )
    if h["perception"] == "states":
        return
    off = {**GEOMETRY_OFF, **({"projection": False} if h["perception"] == "pixels" else {})}
    on = {name: h[name] for name, value in off.items() if h[name] != value}
    if on:
        raise ValueError(
            f"perception: {h['perception']} gives no 3D state"
            + (" and no image box" if h["perception"] == "pixels" else "")
            + ", so no geometry or prior applies; set "
            + ", ".join(f"{name}: {off[name]}" for name in on)
            + f" (got {on})"
        )
    if h["perception"] == "pixels" and (
        h["code_size"] < 1 or h["perception_steps"] < 0 or h["perception_frames"] < 1
    ):
        raise ValueError(
            f"perception: pixels needs code_size >= 1, perception_steps >= 0 and "
            f"perception_frames >= 1, got {h['code_size']}, {h['perception_steps']}, "
            f"{h['perception_frames']}"
        )


def _check_sizes(h: Mapping[str, Any]) -> None:
    """Refuse sizes, precisions and learning rates that are not positive."""
    if h["hidden_size"] < 1 or h["message_size"] < 1:
        raise ValueError(
            f"hidden_size and message_size must be >= 1, got {h['hidden_size']}, {h['message_size']}"
        )
    if h["min_std"] <= 0 or h["learning_rate"] <= 0:
        raise ValueError(
            f"min_std and learning_rate must be > 0, got {h['min_std']}, {h['learning_rate']}"
        )


def _check_mixture(h: Mapping[str, Any]) -> None:
    """Refuse too few Gaussians, and landing options without the landing Gaussian."""
    if h["components"] < 1:
        raise ValueError(
            f"components must be >= 1 (Gaussians in the mixture over a slot's next "
            f"state), got {h['components']}"
        )
    if h["landing_component"] and h["components"] < 2:
        raise ValueError(
            f"landing_component needs components >= 2 (one Gaussian for landing, the others "
            f"for moving on), got components={h['components']}"
        )
    if not h["landing_change"] and not h["landing_component"]:
        raise ValueError(
            "landing_change: false needs landing_component: true (it is the "
            "landing Gaussian's learned change that it leaves out)"
        )
    if h["pivot_landing"] and not h["landing_component"]:
        raise ValueError(
            "pivot_landing needs landing_component: true (it says where the "
            "landing Gaussian lays an object), got landing_component=false"
        )


def _check_withholding(h: Mapping[str, Any]) -> None:
    """Refuse a withheld share outside [0, 1] or spans shorter than a frame."""
    if not 0 <= h["withhold"] <= 1 or h["withhold_frames"] < 1:
        raise ValueError(
            f"withhold must be in [0, 1] (a share of each clip's objects) and "
            f"withhold_frames >= 1, got {h['withhold']}, {h['withhold_frames']}"
        )

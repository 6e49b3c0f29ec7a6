"""Physics-blind followers of per-object inputs (issue 70): rules that know no dynamics, scored
as a parameter-free ``SurpriseModel`` over what a learner that reads objects reads, so
``test --model voe_lightning.model.ObjectFollower`` tells whether a concept can be passed from
those inputs without physics. A concept a follower passes is a shortcut in the stimuli (or, for
unchangeableness' attribute memory, the concept itself).

Three inputs: ``states`` (the record's amodal 3D ``objects``, read only while an object is
seen, as the 3D-state learner reads them), ``masks`` (what a camera and a tracker give: each
mask id's image centroid, area and mean colour, ``object_state.masks.per_id``) and ``rgbd``
(the masks' measures and what the RGB-D rung reads of the depth image, the mean depth of each
id's visible pixels, which joins the centroid in its position, and the largest size each id
has shown, which joins its attributes: *attributes* is then "the largest size stays" too)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.model.base import SurpriseModel
from voe_lightning.model.object_state.masks import per_id
from voe_lightning.model.object_state.rgbd import largest_shown, mean_depth

#: The rules, each an expectation with no dynamics, and what it is surprised by at frame t.
RULES: dict[str, str] = {
    "stay_put": "distance of each seen object from where it was last seen",
    "attributes": "change of each seen object's attributes (size, colour, shape) since last seen",
    "seen_again": "objects seen before that are not seen now",
    "same_and_seen": "seen_again + attributes, counted (motion allowed)",
    "nothing_changes": "seen_again + attributes + stay_put, counted: nothing leaves, moves, changes",
    "copy_last": "squared error of each feature predicted as its value at the frame before",
    "linear_extrapolation": "squared error of each feature predicted as 2 x_{t-1} - x_{t-2}",
}
INPUTS = ("states", "masks", "rgbd")
#: What counts as a change for the counted rules: a move (m for states, image-plane units of
#: half the height for masks, both for rgbd's centroid and depth) and an attribute difference
#: (its Euclidean norm).
MOVE_TOLERANCE = {"states": 0.01, "masks": 0.05, "rgbd": 0.05}
ATTRIBUTE_TOLERANCE = 0.02
#: The record fields each input is read from (``inputs_read``).
READS = {"states": ("objects",), "masks": ("mask",), "rgbd": ("mask", "depth")}


def state_features(objects: TensorDictBase) -> dict[str, torch.Tensor]:
    """``seen`` [B, T, K], ``position`` [..., 3] and ``attributes`` [..., 3 + 3 + shapes]
    (half-extents, colour, one-hot shape) of the record's per-object states."""
    shape = torch.nn.functional.one_hot(
        objects["shape_label"].long(), len(specs.OBJECT_SHAPES)
    ).float()
    attributes = torch.cat([objects["size"].float(), objects["color"].float(), shape], dim=-1)
    return {
        "seen": objects["visible_fraction"] > 0,
        "position": objects["position"].float(),
        "attributes": attributes,
    }


def mask_features(mask: torch.Tensor, frames: torch.Tensor) -> dict[str, torch.Tensor]:
    """``seen``, ``position`` (image centroid) and ``attributes`` (area, mean colour) of each
    mask id but the background's (0), from what frame t shows alone."""
    return _measured_features(per_id(mask, frames))


def _measured_features(measured: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``mask_features`` of ``per_id``'s measures."""
    seen = measured["pixels"] > 0
    seen[..., 0] = False
    return {
        "seen": seen,
        "position": measured["centroid"],
        "attributes": torch.cat([measured["area"][..., None], measured["colour"]], dim=-1),
    }


def rgbd_features(
    mask: torch.Tensor, frames: torch.Tensor, depth: torch.Tensor
) -> dict[str, torch.Tensor]:
    """``mask_features`` with what the RGB-D rung reads of the depth image (``depth``
    [B, T, K, 3], ``specs.depth_spec``): each id's mean depth joins its position, and the
    largest size it has shown (``largest_shown``) its attributes."""
    measured = per_id(mask, frames)
    features = _measured_features(measured)
    mean = mean_depth(depth.to(mask.device))
    largest = largest_shown(measured["half"], mean, features["seen"])
    return {
        "seen": features["seen"],
        "position": torch.cat([features["position"], mean], dim=-1),
        "attributes": torch.cat([features["attributes"], largest], dim=-1),
    }


def last_seen(value: torch.Tensor, seen: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per frame t, each id's ``value`` at the last frame before t that saw it [B, T, K, F], and
    whether there was one [B, T, K]."""
    steps = value.shape[1]
    held, known = torch.zeros_like(value[:, 0]), torch.zeros_like(seen[:, 0])
    before, was = [], []
    for t in range(steps):
        before.append(held)
        was.append(known)
        held = torch.where(seen[:, t, :, None], value[:, t], held)
        known = known | seen[:, t]
    return torch.stack(before, 1), torch.stack(was, 1)


def previous(value: torch.Tensor, lag: int) -> torch.Tensor:
    """``value`` shifted ``lag`` frames later along time (the first ``lag`` frames repeat
    frame 0)."""
    return torch.cat([value[:, :1].expand(-1, lag, *value.shape[2:]), value[:, :-lag]], dim=1)


def follower_inputs(
    features: str,
    frames: torch.Tensor,
    mask: torch.Tensor | None,
    objects: TensorDictBase | None,
    depth: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """``seen``, ``position`` and ``attributes`` of each id from the records' states
    (``features`` ``states``), from the masks and frames (``masks``) or from those and the
    depth measures (``rgbd``), refused by name where the data lacks that input."""
    if features == "states":
        if objects is None:
            raise ValueError(
                "ObjectFollower features 'states' reads the records' objects, and this "
                "data has none: use features 'masks'"
            )
        return state_features(objects)
    if mask is None:
        raise ValueError(f"ObjectFollower features {features!r} needs masks; this data has none")
    if features == "masks":
        return mask_features(mask, frames)
    if depth is None:
        raise ValueError(
            "ObjectFollower features 'rgbd' reads the records' depth (stimuli version 13 on), "
            "and this data has none: use features 'masks'"
        )
    return rgbd_features(mask, frames, depth)


def rule_surprise(rule: str, features: str, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
    """Per-frame surprise [B, T] of ``rule`` (``RULES``) over ``follower_inputs``, summed
    over the ids."""
    seen = inputs["seen"]
    if rule in ("copy_last", "linear_extrapolation"):
        return _extrapolation_error(rule, inputs)
    moved = _change_since_seen(inputs["position"], seen)
    changed = _change_since_seen(inputs["attributes"], seen)
    gone = (last_seen(seen[..., None].float(), seen)[1] & ~seen).float()
    if rule == "stay_put":
        return moved.sum(-1)
    if rule == "attributes":
        return changed.sum(-1)
    if rule == "seen_again":
        return gone.sum(-1)
    count = gone + (changed > ATTRIBUTE_TOLERANCE).float()
    if rule == "nothing_changes":
        count = count + (moved > MOVE_TOLERANCE[features]).float()
    return count.sum(-1)


def _change_since_seen(value: torch.Tensor, seen: torch.Tensor) -> torch.Tensor:
    """Per frame and id, the distance of a seen id's ``value`` from its last seen one (0 for an
    id not seen now or never seen before)."""
    before, known = last_seen(value, seen)
    distance = (value - before).norm(dim=-1)
    return torch.where(seen & known, distance, 0.0)


def _extrapolation_error(rule: str, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
    """Squared error of the features (position, attributes) of ids seen at t and at the frames
    the prediction reads."""
    value = torch.cat([inputs["position"], inputs["attributes"]], dim=-1)
    seen = inputs["seen"]
    if rule == "copy_last":
        predicted, valid = previous(value, 1), seen & previous(seen, 1)
    else:
        predicted = 2 * previous(value, 1) - previous(value, 2)
        valid = seen & previous(seen, 1) & previous(seen, 2)
    valid[:, 0] = False
    if rule == "linear_extrapolation" and value.shape[1] > 1:
        valid[:, 1] = False
    error = ((value - predicted) ** 2).sum(-1)
    return torch.where(valid, error, 0.0).sum(-1)


class ObjectFollower(SurpriseModel):
    """Per-frame surprise of a physics-blind rule over per-object inputs, summed over the ids
    (``RULES`` says what each is surprised by). It has no parameters: it needs no checkpoint
    and cannot be trained. Frame t's surprise reads frames, masks and states up to t. Given, for
    the counted rules only: what counts as a change (``MOVE_TOLERANCE``, ``ATTRIBUTE_TOLERANCE``).

    Args:
        rule: one of ``RULES``.
        features: ``states`` (the record's ``objects``, read while seen), ``masks`` or
            ``rgbd`` (the masks and the record's ``depth``).
    """

    SURPRISE = "a physics-blind follower of per-object inputs"

    def __init__(self, rule: str = "stay_put", features: str = "states"):
        super().__init__()
        if rule not in RULES:
            raise ValueError(f"unknown rule {rule!r}; valid rules are: {', '.join(RULES)}")
        if features not in INPUTS:
            raise ValueError(f"unknown features {features!r}; valid are: {', '.join(INPUTS)}")
        self.save_hyperparameters()
        self.rule, self.features = rule, features

    def inputs_read(self) -> frozenset[str]:
        """The states, the masks, or the masks and depth, as ``features`` says."""
        return frozenset(READS[self.features])

    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
        depth: torch.Tensor | None = None,
    ) -> torch.Tensor:
        inputs = follower_inputs(self.features, frames, mask, objects, depth)
        return rule_surprise(self.rule, self.features, inputs)

    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
        depth: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The frame before (a follower predicts objects, not pixels; frame 0: itself)."""
        return previous(specs.to_model_input(frames), 1)

    def trajectories(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
        depth: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """The rule's per-frame surprise and its running total, a course [B, T, 2]."""
        value = self.surprise(frames, mask, camera, objects, depth)
        return {"follower": torch.stack([value, value.cumsum(dim=1)], dim=-1)}

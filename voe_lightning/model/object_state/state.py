"""What the positive control reads and keeps of each object: the named parts of its state, what
perfect perception reports of a batch of videos (``observe``), the slots after a frame and
training's withheld observations."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase

from voe_lightning import specs

#: The continuous state of an object that the model predicts: position (3), orientation (4),
#: size (3), colour (3). A sphere's orientation cannot be seen, so it reads as the identity.
STATE_SIZE = 13
#: Where each part lies in a state: position, orientation (w, x, y, z), size, colour; what an
#: object is (``IDENTITY``: size and colour) against where it is and how it is turned (``POSE``).
POSITION, ORIENTATION, SIZE, COLOR = slice(0, 3), slice(3, 7), slice(7, 10), slice(10, 13)
POSE, IDENTITY = slice(0, 7), slice(7, 13)
#: Where each part lies in a ``view``: camera coordinates, image-box centre and half-extents.
CAMERA_XYZ, BOX_CENTRE, BOX_HALF = slice(0, 3), slice(3, 5), slice(5, 7)
SHAPES = len(specs.OBJECT_SHAPES)
SPHERE = specs.OBJECT_SHAPES.index("sphere")
#: The per-slot terms of a frame's negative log-likelihood; ``appear`` is per frame.
SLOT_TERMS = ("visibility", "state", "shape", "newcomer_state", "newcomer_shape")


@dataclass(frozen=True)
class StateLayout:
    """What a slot's state holds, by perception: its ``size``, where it is (``position``: what
    moves, whose change is the velocity), how big it is (``extent``), its ``color`` and how it
    is turned (``orientation``; None where perception gives none)."""

    size: int
    position: slice[int]
    extent: slice[int]
    color: slice[int]
    orientation: slice[int] | None

    @property
    def position_size(self) -> int:
        return self.position.stop - self.position.start

    @property
    def extent_size(self) -> int:
        return self.extent.stop - self.extent.start

    @property
    def orientation_size(self) -> int:
        return 0 if self.orientation is None else self.orientation.stop - self.orientation.start


#: Perfect 3D perception's state (``observe``).
STATES = StateLayout(STATE_SIZE, POSITION, SIZE, COLOR, ORIENTATION)


@dataclass
class Observations:
    """What perfect perception reports of a batch of videos, per video over the mask ids
    ``ids`` [B, S] it shows (``observe``): ``state`` [B, T, S, 13] and ``shape`` one-hot
    [B, T, S, 7] (zero where hidden), ``fraction`` [B, T, S] visible share of the frame,
    ``visible`` bool [B, T, S]; ``camera`` [B, T, 6] poses."""

    ids: torch.Tensor
    state: torch.Tensor
    shape: torch.Tensor
    fraction: torch.Tensor
    visible: torch.Tensor
    camera: torch.Tensor


def slot_ids(seen: torch.Tensor) -> torch.Tensor:
    """The ids [B, S] that are each video's slots, from which ids are ``seen`` (bool
    [B, T, K], per frame and id; id 0 the background): the ids it shows, in the order they are
    first seen (then by id), padded with ids it never shows, so a slot that joins later takes a
    later place."""
    steps, count = seen.shape[1:]
    first = torch.where(seen.any(1), seen.float().argmax(1), steps)  # [B, K]; T: never
    first[:, 0] = steps + 1  # the background is no object
    order = (first * count + torch.arange(count, device=seen.device)).argsort(dim=1)
    return order[:, : int((first <= steps - 1).sum(1).max())]


def by_slot(value: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
    """Per-id ``value`` [B, T, K, ...] taken at each video's slot ``ids`` [B, S]: [B, T, S, ...]."""
    index = ids[:, None].expand(-1, value.shape[1], -1)
    index = index.reshape(*index.shape, *([1] * (value.dim() - 3))).expand(
        -1, -1, -1, *value.shape[3:]
    )
    return value.gather(2, index)


def observe(objects: TensorDictBase, camera: torch.Tensor) -> Observations:
    """The visible objects' states of batched ``objects`` (``specs.objects_spec`` [B, T, K]):
    every state of an object is zeroed at the frames where it has no visible pixel, so nothing
    hidden reaches the model. Each video's slots are the mask ids it shows, in the order they
    are first seen (then by id), padded with ids it never shows: a slot that joins later takes
    a later place, and empty slots add exact zeros, so nothing before it changes."""
    ids = slot_ids(objects["visible_fraction"] > 0)
    picked = {name: by_slot(value, ids) for name, value in objects.items()}  # [B, T, S, ...]
    visible = picked["visible_fraction"] > 0
    label = picked["shape_label"].long()
    orientation = picked["orientation"].float()
    orientation = orientation * torch.where(orientation[..., :1] < 0, -1.0, 1.0)  # w >= 0
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], device=orientation.device)
    orientation = torch.where((label == SPHERE)[..., None], identity, orientation)
    state = torch.cat(
        [picked["position"].float(), orientation, picked["size"].float(), picked["color"].float()],
        dim=-1,
    )
    keep = visible[..., None].float()
    return Observations(
        ids=ids,
        state=state * keep,
        shape=F.one_hot(label, SHAPES).float() * keep,
        fraction=picked["visible_fraction"].float() * visible,
        visible=visible,
        camera=camera.float(),
    )


def by_object_count(observations: Observations) -> list[Observations]:
    """The batch's clips grouped by how many objects each shows, each group with that many
    slots: a clip's rollout reads no other clip, so the groups' terms sum to the batch's, while
    no slot pair is run for a slot its clip never fills (a clip of one object, padded to a
    batch's five, ran 20 slot pairs for none)."""
    shown = observations.visible.any(1).sum(-1)  # [B]; a clip's shown ids fill its first slots
    groups = []
    for count in shown.unique().tolist():  # type: ignore[no-untyped-call]  # Tensor.unique: unannotated in torch
        clips = (shown == count).nonzero()[:, 0]
        per_slot = {
            name: getattr(observations, name)[clips][:, :, :count]
            for name in ("state", "shape", "fraction", "visible")
        }
        groups.append(
            Observations(
                ids=observations.ids[clips][:, :count],
                camera=observations.camera[clips],
                **per_slot,
            )
        )
    return groups


@dataclass
class Slots:
    """The slots after a frame, each [B, S, ...]: ``hidden`` recurrent states, ``belief`` (the
    last state seen or, while hidden, predicted), ``shape`` one-hot, the last ``velocity`` and
    ``known`` (seen at some frame so far)."""

    hidden: torch.Tensor
    belief: torch.Tensor
    shape: torch.Tensor
    velocity: torch.Tensor
    known: torch.Tensor


def empty_slots(observations: Observations, hidden_size: int, layout: StateLayout) -> Slots:
    """The slots before frame 0: none known, all zeros."""
    batch, _, count = observations.visible.shape
    zeros = observations.state.new_zeros
    return Slots(
        hidden=zeros(batch, count, hidden_size),
        belief=zeros(batch, count, layout.size),
        shape=zeros(batch, count, SHAPES),
        velocity=zeros(batch, count, layout.position_size),
        known=torch.zeros(batch, count, dtype=torch.bool, device=observations.state.device),
    )


def withheld_spans(
    shape: torch.Size, share: float, longest: int, device: torch.device
) -> torch.Tensor | None:
    """Training's withheld observations, bool [B, T, S]: each (clip, slot) with probability
    ``share`` gets one span of 1 to ``longest`` frames, starting at a frame from 1 on, during
    which the model is not told what it sees. An object truly hidden in a clip has no target
    until it reappears, so without these spans a hidden object's rollout learns only from that
    frame, and drifts (a cube at rest behind a container: 0.2 m over nine frames). None if
    there is nothing to withhold."""
    if share <= 0:
        return None
    batch, steps, slots = shape
    chosen = torch.rand(batch, 1, slots, device=device) < share
    start = torch.randint(1, max(steps, 2), (batch, 1, slots), device=device)
    length = torch.randint(1, longest + 1, (batch, 1, slots), device=device)
    time = torch.arange(steps, device=device)[None, :, None]
    return chosen & (time >= start) & (time < start + length)

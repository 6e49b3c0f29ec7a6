"""Object slots from segmentation masks (PLATO's perception input): which object ids a video
holds, in which slot each one goes, and each slot's binary mask per frame."""

from __future__ import annotations

from dataclasses import dataclass

import torch

#: Largest move of an object's mask centroid between two consecutive frames that both show it,
#: as a fraction of the frame's diagonal. Our generator's largest over 20 seeds of every clip
#: kind and probe variant is 0.34 (a screen entering the view in unchangeableness); a larger
#: move means the id was handed to another object (masks numbered per frame, not per object).
MAX_MASK_JUMP = 0.5


@dataclass
class Slots:
    """Slot 0 is the background (mask id 0, seen in every frame); slots 1..K hold the video's
    object ids in the order they are first seen (ids first seen in the same frame in increasing
    order), then padding (id 0, never seen). A slot is created when its id is first seen:
    before that frame it is not ``seen``, exactly like a padding slot, so an id that first
    appears at frame f changes nothing the model computes for frames before f."""

    ids: torch.Tensor  # int64 [B, K + 1]
    seen: torch.Tensor  # bool [B, T, K + 1], whether the slot's id was seen at frames <= t
    masks: torch.Tensor  # float32 [B, T, K + 1, H, W], 1 where the slot's object is seen


def video_name(index: int, seeds: torch.Tensor | None) -> str:
    """How errors name a video of a batch: its seed when the batch has seeds."""
    if seeds is None:
        return f"video {index} of the batch"
    return f"video {index} of the batch (seed {int(seeds.reshape(-1)[index])})"


def require_mask(
    mask: torch.Tensor | None, frames: torch.Tensor, seeds: torch.Tensor | None = None
) -> torch.Tensor:
    """The mask of ``frames`` [B, T, H, W, 3], refusing a missing or misshapen one clearly."""
    expected = tuple(frames.shape[:-1])
    if mask is None:
        raise ValueError(
            f"the object-centric model needs each video's object-id mask uint8 {list(expected)} "
            f"(batch key 'mask', 0 = background), but {video_name(0, seeds)} came without "
            "one; use records with masks, or the object-free twin (object_free: true)"
        )
    if tuple(mask.shape) != expected:
        raise ValueError(
            f"mask must be shaped {list(expected)} like the frames, got "
            f"{list(mask.shape)} ({video_name(0, seeds)})"
        )
    return mask


def object_slots(
    mask: torch.Tensor,
    num_slots: int,
    seeds: torch.Tensor | None = None,
    max_jump: float | None = MAX_MASK_JUMP,
) -> Slots:
    """Assign the ids of ``mask`` uint8 [B, T, H, W] to ``num_slots`` object slots plus the
    background slot, causally (see ``Slots``). An id keeps its slot from the frame it is first
    seen to the end of the video: an object that vanishes (say, behind an occluder) and
    reappears has an empty mask while hidden, never a new slot. More ids than slots, an id that
    jumps more than ``max_jump`` of the frame diagonal between two frames (``refuse_jumps``;
    None: no check, as for a sample of a clip's frames), or a batch with no object at all, is
    refused naming the video."""
    batch, steps = mask.shape[:2]
    ids = torch.zeros(batch, num_slots + 1, dtype=torch.int64, device=mask.device)
    first = torch.full((batch, num_slots + 1), steps, dtype=torch.int64, device=mask.device)
    first[:, 0] = 0
    for index in range(batch):
        found = torch.unique(mask[index])
        found = found[found != 0]
        if found.numel() > num_slots:
            per_frame = max(int((torch.unique(frame) != 0).sum()) for frame in mask[index])
            hint = "raise num_slots"
            if per_frame <= num_slots:
                hint = (
                    f"no frame shows more than {per_frame} at once: if the ids number each "
                    "frame's objects rather than the video's, renumber them by object "
                    "(each id one object for the whole video); otherwise raise num_slots"
                )
            raise ValueError(
                f"{video_name(index, seeds)} shows {found.numel()} objects (mask ids "
                f"{found.tolist()}), more than num_slots={num_slots}; {hint}"
            )
        shown = (mask[index, :, None] == found[None, :, None, None]).flatten(2).any(-1)  # [T, K]
        appears = shown.int().argmax(0)  # the first frame that shows each id
        appears, order = torch.sort(appears, stable=True)  # ties keep increasing ids
        ids[index, 1 : 1 + found.numel()] = found[order].long()
        first[index, 1 : 1 + found.numel()] = appears
    if not bool((first[:, 1:] < steps).any()):
        raise ValueError(
            f"no video of the batch shows an object (every mask is 0, e.g. "
            f"{video_name(0, seeds)}): the object-centric model needs segmentation masks "
            "(IntPhys records carry zero masks); use the object-free twin (object_free: true)"
        )
    frame = torch.arange(steps, device=mask.device)
    seen = frame[None, :, None] >= first[:, None, :]  # [B, T, K + 1]
    masks = mask.long()[:, :, None] == ids[:, None, :, None, None]  # [B, T, K + 1, H, W]
    masks &= seen[..., None, None]  # padding slots (id 0) see nothing
    if max_jump is not None:
        refuse_jumps(masks[:, :, 1:], ids[:, 1:], seeds, max_jump)
    return Slots(ids=ids, seen=seen, masks=masks.float())


def centroid_moves(masks: torch.Tensor) -> torch.Tensor:
    """How far each slot's mask centroid moves between consecutive frames, as a fraction of the
    frame diagonal: masks bool [B, T, K, H, W] -> [B, T - 1, K], 0 unless both frames show it."""
    height, width = masks.shape[-2:]
    weights = masks.float()
    pixels = weights.sum((-2, -1))  # [B, T, K]
    rows = torch.arange(height, device=masks.device, dtype=torch.float32)
    columns = torch.arange(width, device=masks.device, dtype=torch.float32)
    centre = (
        torch.stack([(weights.sum(-1) * rows).sum(-1), (weights.sum(-2) * columns).sum(-1)], dim=-1)
        / pixels.clamp(min=1)[..., None]
    )  # [B, T, K, 2]
    move = (centre[:, 1:] - centre[:, :-1]).norm(dim=-1) / (height**2 + width**2) ** 0.5
    return torch.where((pixels[:, 1:] > 0) & (pixels[:, :-1] > 0), move, torch.zeros_like(move))


def refuse_jumps(
    masks: torch.Tensor,
    ids: torch.Tensor,
    seeds: torch.Tensor | None,
    max_jump: float = MAX_MASK_JUMP,
) -> None:
    """Refuse an object id whose mask centroid moves more than ``max_jump`` of the frame
    diagonal between consecutive frames that both show it (masks bool [B, T, K, H, W]): a slot
    must follow one object, or the dynamics learn teleports."""
    move = centroid_moves(masks)
    if bool((move > max_jump).any()):
        video, frame, slot = (int(i) for i in (move > max_jump).nonzero()[0])
        raise ValueError(
            f"{video_name(video, seeds)}: mask id {int(ids[video, slot])} jumps "
            f"{float(move[video, frame, slot]):.2f} of the frame diagonal between frames {frame} "
            f"and {frame + 1} (at most max_mask_jump={max_jump} expected): each id must name one "
            "object for the whole video; renumber per-frame masks by object (track them) "
            "first, or raise max_mask_jump where objects really move that fast"
        )


def whole_frame_slot(frames: torch.Tensor) -> Slots:
    """The object-free twin's single slot: the whole frame, seen in every frame."""
    batch, steps, height, width = frames.shape[:4]
    device = frames.device
    return Slots(
        ids=torch.zeros(batch, 1, dtype=torch.int64, device=device),
        seen=torch.ones(batch, steps, 1, dtype=torch.bool, device=device),
        masks=torch.ones(batch, steps, 1, height, width, device=device),
    )

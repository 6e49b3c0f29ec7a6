"""The pixel rung of the learner's perception: what a learned encoder makes of each tracked
object's pixels, with no hand-written measurement. Per frame and visible mask id, PLATO's object
autoencoder (``object_centric.perception``) encodes the frame masked to the id's pixels, and the
code is the object's state; the autoencoder learns first, from the training clips' frames, then
is frozen while the dynamics learn over its codes."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from voe_lightning import specs
from voe_lightning.model.object_centric.perception import (
    Perception,
    autoencoder_terms,
    compose,
)
from voe_lightning.model.object_centric.slots import Slots as MaskSlots
from voe_lightning.model.object_state.masks import per_id
from voe_lightning.model.object_state.state import (
    SHAPES,
    Observations,
    StateLayout,
    by_slot,
    slot_ids,
)

#: The encoder's stride-2 convolutions (PLATO's, sized for a CPU as configs/object_centric.yaml).
CHANNELS = (16, 32, 32, 64)


def code_layout(code_size: int) -> StateLayout:
    """A learned code's state layout: the whole code is what moves (its change is the
    velocity, its differences the pairs'), with no extent, colour or orientation to name."""
    return StateLayout(
        code_size,
        position=slice(0, code_size),
        extent=slice(code_size, code_size),
        color=slice(code_size, code_size),
        orientation=None,
    )


def object_encoder(code_size: int, image_size: tuple[int, int]) -> Perception:
    """The variational object autoencoder of frames ``image_size`` (H, W), ``code_size`` wide."""
    height, width = image_size
    return Perception((height, width), code_size, CHANNELS, variational=True)


def observe_pixels(
    encoder: Perception, mask: torch.Tensor, frames: torch.Tensor, camera: torch.Tensor
) -> Observations:
    """What the pixel rung reads of a batch of videos: per slot (a mask id, ordered as
    ``state.observe`` orders them) and frame, the encoder's mean code of the frame masked to the
    id's pixels where it has any (zeros where hidden), its area as the visible share, no shape
    and the camera poses. Frame t's observations read frame t alone."""
    pixels = per_id(mask, frames)["pixels"]
    ids = slot_ids(pixels > 0)
    area = by_slot(pixels, ids) / (mask.shape[-2] * mask.shape[-1])
    visible = area > 0
    masks = (mask.long()[:, :, None] == ids[:, None, :, None, None]).float()  # [B, T, S, H, W]
    x = specs.to_model_input(frames)  # [B, T, 3, H, W]
    which = visible.nonzero(as_tuple=True)  # encode only the seen (clip, frame, slot)s
    seen_codes, _ = encoder.encode(x[which[:2]], masks[which][:, None])
    state = seen_codes.new_zeros(*visible.shape, encoder.code_size)
    state[which] = seen_codes[:, 0]
    return Observations(
        ids=ids,
        state=state,
        shape=state.new_zeros(*visible.shape, SHAPES),
        fraction=area,
        visible=visible,
        camera=camera.float(),
    )


def encoder_terms(
    encoder: Perception,
    mask: torch.Tensor,
    frames: torch.Tensor,
    frames_per_clip: int,
) -> dict[str, torch.Tensor]:
    """The autoencoder's loss per clip (``perception.autoencoder_terms``, its KL and mask terms
    weighed 1, as configs/object_centric.yaml's) on
    ``frames_per_clip`` random frames of each clip: its slots the video's mask ids, in the
    order ``observe_pixels`` takes them, and the background as one more slot."""
    steps = torch.randperm(frames.shape[1], device=frames.device)[:frames_per_clip].sort().values
    mask, frames = mask[:, steps], frames[:, steps]
    ids = slot_ids(per_id(mask, frames)["pixels"] > 0)
    ids = torch.cat([torch.zeros_like(ids[:, :1]), ids], dim=1)  # slot 0: the background
    masks = (mask.long()[:, :, None] == ids[:, None, :, None, None]).float()
    slots = MaskSlots(ids=ids, seen=masks.flatten(3).any(-1), masks=masks)
    x = specs.to_model_input(frames)
    return autoencoder_terms(encoder, x, slots, kl_weight=1.0, mask_loss_weight=1.0)


def background_codes(encoder: Perception, mask: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
    """The code of each frame's background (mask id 0) [B, T, C], which the expected frames are
    composed over."""
    x = specs.to_model_input(frames).flatten(0, 1)
    mean, _ = encoder.encode(x, (mask == 0).float().flatten(0, 1)[:, None])
    return mean.view(*mask.shape[:2], -1)


def paint_codes(
    encoder: Perception, codes: torch.Tensor, opacity: torch.Tensor, background: torch.Tensor
) -> torch.Tensor:
    """What the slots' ``codes`` [B, T, S, C] look like, decoded [B, T, 3, H, W] and composed
    as the autoencoder learned to compose a frame (``perception.compose``) over the
    ``background`` code [B, T, C], each slot's mask logits raised by the log of its
    ``opacity`` [B, T, S] (the probability that it is seen): a slot expected hidden shows
    nothing."""
    everything = torch.cat([background[:, :, None], codes], dim=2).flatten(0, 1)
    rgb, logits = encoder.decode(everything)  # [N, 1 + S, 3, H, W], [N, 1 + S, H, W]
    seen = F.pad(opacity.flatten(0, 1), (1, 0), value=1.0).log()  # the background: always
    image, _ = compose(rgb, logits + seen[..., None, None], torch.ones_like(seen, dtype=torch.bool))
    return image.view(*codes.shape[:2], *image.shape[1:])

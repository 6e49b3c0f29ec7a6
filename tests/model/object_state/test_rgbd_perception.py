"""The RGB-D rung of the learner (``perception: rgbd``): what it reads of a video is the mask
rung's measures of each id's pixels and the record's ``depth`` measures of the same id, in the
slots the masks give, nothing while hidden; the mask rung reads exactly what it read before when
a depth is there too; the RGB-D rung never reads the amodal ``objects``, is given ``depth`` where
the probes carry it (and no other model is), refuses a batch without it in one line, and learns."""

import pytest
import torch
import torch.nn.functional as F
from helpers.training import losses_over_steps
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.base import SurpriseModel, video_inputs
from voe_lightning.model.object_state.arguments import GEOMETRY_OFF
from voe_lightning.model.object_state.masks import observe_masks, observe_measured, per_id, seen_box
from voe_lightning.model.object_state.rgbd import RGBD, observe_rgbd, observe_rgbd_measured

SLOTS = specs.OBJECT_SLOTS
RGBD_OPTIONS = dict(perception="rgbd", hidden_size=8, message_size=4, **GEOMETRY_OFF)


def hand_made() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A 4x4 video of two frames: id 1 (red) fills the top-left 2x2 at frame 0 and is hidden at
    frame 1; id 2 (green) one pixel at row 2, column 2 at both; id 3 (blue) one pixel at row 3,
    column 3 from frame 1. Its depth has junk where an id is not seen (id 1 at frame 1, id 5)."""
    mask = torch.zeros(1, 2, 4, 4, dtype=torch.uint8)
    mask[0, 0, :2, :2] = 1
    mask[0, :, 2, 2] = 2
    mask[0, 1, 3, 3] = 3
    colours = torch.tensor([[128, 128, 128], [255, 0, 0], [0, 255, 0], [0, 0, 255]])
    frames = colours[mask.long()].to(torch.uint8)  # [1, 2, 4, 4, 3]
    depth = torch.zeros(1, 2, SLOTS, 3)
    depth[0, 0, 1] = torch.tensor([3.0, 2.5, 0.25])
    depth[0, 0, 2] = torch.tensor([4.0, 4.0, 1.0])
    depth[0, 1, 2] = torch.tensor([4.5, 4.25, 0.5])
    depth[0, 1, 3] = torch.tensor([2.0, 1.5, 0.0])
    depth[0, 1, 1] = 9.0  # id 1 hidden at frame 1: never read
    depth[0, :, 5] = 7.0  # id 5 never seen
    return mask, frames, depth


def test_each_slot_reads_its_ids_pixels_and_depth_and_nothing_while_hidden():
    mask, frames, depth = hand_made()
    camera = torch.zeros(1, 2, 6)
    observed = observe_rgbd(mask, frames, depth, camera)
    assert observed.ids.tolist() == [[1, 2, 3]]  # in the order first seen
    assert observed.visible[0].tolist() == [[True, True, False], [False, True, True]]
    # [cx, cy, mean depth | hx, hy, area, largest hx, hy times the depth | r, g, b]: the least
    # depth and the cut share unread; id 2's largest grows with its depth, never shrinks
    expected = torch.tensor(
        [
            [
                [-0.5, 0.5, 3.0, 0.5, 0.5, 0.25, 1.5, 1.5, 1, 0, 0],
                [0.25, -0.25, 4.0, 0.25, 0.25, 1 / 16, 1.0, 1.0, 0, 1, 0],
                [0.0] * 11,
            ],
            [
                [0.0] * 11,
                [0.25, -0.25, 4.5, 0.25, 0.25, 1 / 16, 1.125, 1.125, 0, 1, 0],
                [0.75, -0.75, 2.0, 0.25, 0.25, 1 / 16, 0.5, 0.5, 0, 0, 1],
            ],
        ]
    )
    torch.testing.assert_close(observed.state[0], expected)
    torch.testing.assert_close(observed.fraction[0], expected[..., 5])
    assert (observed.shape == 0).all()  # no shape label
    assert RGBD.size == 11 and RGBD.position_size == 3
    # the masks' part of the state is exactly the mask rung's
    masks = observe_masks(mask, frames, camera).state
    two_d = torch.cat(
        [observed.state[..., 0:2], observed.state[..., 3:6], observed.state[..., 8:]], -1
    )
    assert torch.equal(two_d, masks)
    with pytest.raises(ValueError, match=r"depth must be \[B, T, 33, 3\].*got \(1, 2, 5, 3\)"):
        per_id(mask, frames, depth[:, :, :5])


def test_the_mask_rung_reads_the_same_with_a_depth_beside_it():
    """``per_id`` adds the depth and changes nothing else, so the mask rung (its shipped
    checkpoint trained without one) observes exactly what it did."""
    mask, frames, depth = hand_made()
    camera = torch.zeros(1, 2, 6)
    alone, beside = per_id(mask, frames), per_id(mask, frames, depth)
    assert set(beside) - set(alone) == {"depth"} and "depth" not in alone
    assert all(torch.equal(alone[name], beside[name]) for name in alone)
    one, other = observe_measured(alone, camera), observe_measured(beside, camera)
    for name in ("ids", "state", "shape", "fraction", "visible", "camera"):
        assert torch.equal(getattr(one, name), getattr(other, name)), name
    assert torch.equal(one.state, observe_masks(mask, frames, camera).state)
    masks = ObjectStateModel(perception="masks", hidden_size=8, message_size=4, **GEOMETRY_OFF)
    assert masks.inputs_read() == frozenset({"mask"})


def synthetic_depth(mask: torch.Tensor, seed: int) -> torch.Tensor:
    """A depth record [B, T, K, 3] for ``mask``: per id and frame seen, a mean depth in [2, 6],
    a least depth up to 0.3 nearer and a cut share, drawn from ``seed``; zeros where unseen."""
    generator = torch.Generator().manual_seed(seed)
    shape = (*mask.shape[:2], SLOTS)
    mean = 2 + 4 * torch.rand(shape, generator=generator)
    near = mean - 0.3 * torch.rand(shape, generator=generator)
    cut = torch.rand(shape, generator=generator)
    seen = F.one_hot(mask.long(), SLOTS).flatten(2, 3).any(2)  # [B, T, K]
    return torch.stack([mean, near, cut], -1) * seen[..., None]


def probes() -> TensorDict:
    """Two solidity probe pairs, each video with a synthetic depth (one draw for both videos,
    so the pair's depths are identical wherever their masks are)."""
    from voe_lightning.scenes import generate_probe

    batch = torch.stack([generate_probe("solidity", "standard", seed) for seed in (0, 1)])
    for side in ("consistent", "inconsistent"):
        batch[side, "depth"] = synthetic_depth(batch[side, "mask"], seed=7)
    return batch


def test_the_rgbd_rungs_surprise_reads_depth_and_never_the_amodal_objects():
    """Issue 70 for the RGB-D rung: removing the probes' ``objects`` leaves every frame's
    surprise exactly as it was; changing the ids' depth from frame t changes what the model
    reads after frame t and not the surprise before; the
    probe step gives it the videos' depth, and a model that does
    not read depth is never given it."""
    from voe_lightning.audit.followers import features_read

    torch.manual_seed(0)
    model = ObjectStateModel(**RGBD_OPTIONS).eval()
    assert model.inputs_read() == frozenset({"mask", "depth"})
    assert features_read(model.inputs_read()) == ("masks", "rgbd")  # its report's followers
    batch = probes()
    for side in ("consistent", "inconsistent"):
        video, camera = batch[side], batch["camera"]
        with_objects = model.surprise(
            video["frames"], video["mask"], camera, video["objects"], depth=video["depth"]
        )
        without = model.surprise(video["frames"], video["mask"], camera, None, depth=video["depth"])
        assert torch.equal(with_objects, without)
    video = batch["inconsistent"]
    changed = video["depth"].clone()
    t = 6
    changed[:, t:, :, 0] += 0.5 * (changed[:, t:, :, 0] > 0)  # every seen id 0.5 m farther
    before = model.surprise(video["frames"], video["mask"], batch["camera"], depth=video["depth"])
    after = model.surprise(video["frames"], video["mask"], batch["camera"], depth=changed)
    assert torch.equal(before[:, :t], after[:, :t])
    # read after t: each clip's state terms differ at every frame after t (their rectified
    # excess, the surprise, may read 0 in an untrained model)
    terms = [
        model.rollout(model._inputs(video["frames"], None, batch["camera"], video["mask"], depth=d))
        for d in (video["depth"], changed)
    ]
    state_before, state_after = (out["state"].sum(-1) for out in terms)
    assert (state_before[:, t + 1 :] != state_after[:, t + 1 :]).all()
    # the probe step hands each video's depth to the rgbd model: as scored alone
    scored = model.probe_step(batch)
    torch.testing.assert_close(scored["surprise_inconsistent"], before)
    assert "depth" in video_inputs(batch, "inconsistent", model.inputs_read())
    masks = ObjectStateModel(perception="masks", hidden_size=8, message_size=4, **GEOMETRY_OFF)
    assert "depth" not in video_inputs(batch, "inconsistent", masks.inputs_read())
    protocol_only = ProtocolOnly()  # its surprise takes no depth: it is not given one
    protocol_only.probe_step(batch)
    assert protocol_only.given == ["frames", "mask", "camera", "objects"]


class ProtocolOnly(SurpriseModel):
    """A model of the protocol alone (no ``depth`` keyword), reading the default inputs."""

    def surprise(self, frames, mask=None, camera=None, objects=None):
        self.given = [
            name
            for name, value in zip(
                ("frames", "mask", "camera", "objects"), (frames, mask, camera, objects)
            )
            if value is not None
        ]
        return torch.zeros(frames.shape[:2])

    def expected_frames(self, frames, mask=None, camera=None, objects=None):
        return torch.zeros(*frames.shape[:2], 3, *frames.shape[2:4])

    def trajectories(self, frames, mask=None, camera=None, objects=None):
        return {}


def test_a_batch_without_depth_is_refused_in_one_line():
    mask, frames, depth = hand_made()
    camera = torch.zeros(1, 2, 6)
    model = ObjectStateModel(**RGBD_OPTIONS)
    message = r"batch key 'depth'; records of stimuli version 13 or later .* carry it$"
    with pytest.raises(ValueError, match=message):
        model.surprise(frames, mask, camera)
    with pytest.raises(ValueError, match="'depth' among its mask_features; records of stimuli"):
        observe_rgbd_measured(per_id(mask, frames), camera)
    held = TensorDict(
        {"mask_features": TensorDict(per_id(mask, frames), batch_size=[1]), "camera": camera},
        batch_size=[1],
    )
    with pytest.raises(ValueError, match="'depth' among its mask_features"):
        model.training_step(held, 0)


def test_the_rgbd_rung_learns_from_masks_frames_and_depth_as_held_or_whole():
    """On synthetic clips (ids moving, near and far), the loss from each clip's ``per_id``
    measures held with its depth is the loss from its mask, frames and depth, and a few Adam
    steps lower it; the networks read the pixels' boxes (``seen_box``), no camera coordinates."""
    torch.manual_seed(0)
    batch_size, steps, size = 3, 6, 16
    mask = torch.zeros(batch_size, steps, size, size, dtype=torch.uint8)
    for clip in range(batch_size):
        for t in range(steps):
            mask[clip, t, 2:6, 1 + t + clip : 5 + t + clip] = 1  # a block moving right
            mask[clip, t, 9 : 12 - (t % 2), 8:14] = 2  # one whose height flickers
    frames = torch.randint(0, 256, (batch_size, steps, size, size, 3), dtype=torch.uint8)
    depth = synthetic_depth(mask, seed=3)
    camera = torch.tensor([0.0, 0.0, 0.4, 4.0, 90.0, -20.0]).expand(batch_size, steps, 6)
    whole = TensorDict(
        {"frames": frames, "mask": mask, "depth": depth, "camera": camera}, batch_size=[batch_size]
    )
    measures = TensorDict(per_id(mask, frames, depth), batch_size=[batch_size])
    held = TensorDict({"mask_features": measures, "camera": camera}, batch_size=[batch_size])
    model = ObjectStateModel(**{**RGBD_OPTIONS, "hidden_size": 16, "message_size": 8})
    model.hparams.withhold = 0.0  # no random spans: the two losses see the same clips
    torch.testing.assert_close(model.training_step(held, 0), model.training_step(whole, 0))
    observed = observe_rgbd(mask, frames, depth, camera)
    box = model._view(observed.state[:, 0], camera[:, 0])
    assert torch.equal(box, seen_box(observed.state[:, 0], RGBD))
    assert (box[..., :3] == 0).all()
    torch.testing.assert_close(box[..., 3:5], observed.state[:, 0, :, 0:2])
    torch.testing.assert_close(box[..., 5:7], observed.state[:, 0, :, 3:5])
    losses = losses_over_steps(model, held, 15)
    assert losses[-1] < losses[0] - 10, losses
    expected = model.expected_frames(frames, mask, camera, depth=depth)
    assert expected.shape == (batch_size, steps, 3, size, size)

"""The mask rung of the learner (``perception: masks``): what it reads of a video is measured
from the mask and frames alone, as a brute-force count of each id's pixels gives it, in the
slots the 3D perception would make; no 3D geometry or prior is accepted with it; and it learns."""

import numpy as np
import pytest
import torch
from helpers.training import losses_over_steps

from voe_lightning.model import ObjectStateModel
from voe_lightning.model.object_state.arguments import GEOMETRY_OFF
from voe_lightning.model.object_state.masks import MASKS, observe_masks, seen_box
from voe_lightning.model.object_state.state import observe
from voe_lightning.scenes import generate_clip


def brute_force(mask: np.ndarray, frames: np.ndarray, object_id: int) -> np.ndarray:
    """The ``MASKS`` state of ``object_id`` in one frame, pixel by pixel (zeros if absent)."""
    height, width = mask.shape
    rows, columns = np.nonzero(mask == object_id)
    if len(rows) == 0:
        return np.zeros(MASKS.size)
    x = (columns + 0.5 - width / 2) / (height / 2)
    y = (height / 2 - rows - 0.5) / (height / 2)
    half_pixel = 1 / height
    colour = frames[rows, columns].astype(np.float64).mean(0) / 255
    return np.array(
        [
            x.mean(),
            y.mean(),
            (x.max() - x.min()) / 2 + half_pixel,
            (y.max() - y.min()) / 2 + half_pixel,
            len(rows) / (height * width),
            *colour,
        ]
    )


@pytest.mark.parametrize("concept", ["containment", "unchangeableness"])
def test_each_slot_reads_what_its_ids_pixels_show_and_nothing_while_hidden(concept):
    clip = generate_clip(concept, "example", seed=3)
    batch = clip[None]
    observed = observe_masks(batch["mask"], batch["frames"], batch["camera"])
    by_states = observe(batch["objects"], batch["camera"])
    # the same slots, in the same order, as perfect perception's (a tracker's ids)
    assert torch.equal(observed.ids, by_states.ids)
    assert torch.equal(observed.visible, by_states.visible)
    mask, frames = batch["mask"][0].numpy(), batch["frames"][0].numpy()
    for slot, object_id in enumerate(observed.ids[0].tolist()):
        for t in range(mask.shape[0]):
            expected = brute_force(mask[t], frames[t], object_id)
            np.testing.assert_allclose(observed.state[0, t, slot].numpy(), expected, atol=1e-5)
    assert observed.visible.any(1).all() and not observed.visible.all()  # someone hides
    assert (observed.state[~observed.visible] == 0).all()
    assert (observed.shape == 0).all()  # no shape label: a camera gives none
    # with projection, the networks read the box the pixels span, and nothing of the camera
    model = ObjectStateModel(perception="masks", hidden_size=8, message_size=4, **GEOMETRY_OFF)
    box = model._view(observed.state[:, 0], batch["camera"][:, 0])
    assert torch.equal(box, seen_box(observed.state[:, 0]))
    assert (box[..., :3] == 0).all()
    torch.testing.assert_close(box[..., 3:5], observed.state[:, 0, :, :2])
    torch.testing.assert_close(box[..., 5:7], observed.state[:, 0, :, 2:4])


def test_3d_geometry_and_priors_are_refused_without_3d_states():
    with pytest.raises(ValueError, match="perception: masks gives no 3D state.*sight_lines"):
        ObjectStateModel(perception="masks", **{**GEOMETRY_OFF, "sight_lines": True})
    with pytest.raises(
        ValueError,
        match=r"perception must be one of \('states', 'masks', 'rgbd', 'pixels'\), got 'lidar'",
    ):
        ObjectStateModel(perception="lidar")


def test_the_mask_rung_learns_from_masks_and_frames():
    """A few Adam steps on real clips lower its negative log-likelihood; a batch without a mask
    is refused, naming the key it needs."""
    torch.manual_seed(0)
    model = ObjectStateModel(perception="masks", hidden_size=32, message_size=16, **GEOMETRY_OFF)
    clips = torch.stack(
        [generate_clip(c, "example", seed=s) for c in ("continuity", "solidity") for s in (0, 1)]
    )
    losses = losses_over_steps(model, clips, 30)
    assert losses[-1] < losses[0] - 50, losses
    with pytest.raises(ValueError, match="batch key 'mask'"):
        model.surprise(clips["frames"], objects=clips["objects"], camera=clips["camera"])


@pytest.mark.parametrize("perception", ["masks", "pixels"])
def test_a_camera_rungs_surprise_is_unchanged_without_the_amodal_objects(perception):
    """Issue 70: the camera rungs read what a camera gives (frames, masks, camera pose), so
    removing the records' amodal ``objects`` from the probes leaves every frame's surprise
    exactly as it was; the rung says so (``inputs_read``), and its report audits the followers
    of masks, not of states."""
    from voe_lightning.audit.followers import features_read
    from voe_lightning.scenes import generate_probe

    torch.manual_seed(0)
    options = dict(perception=perception, hidden_size=8, message_size=4, **GEOMETRY_OFF)
    if perception == "pixels":
        options["projection"] = False
    model = ObjectStateModel(**options).eval()
    assert model.inputs_read() == frozenset({"mask"}) and features_read(model.inputs_read()) == (
        "masks",
    )
    batch = torch.stack([generate_probe("solidity", "standard", seed) for seed in (0, 1)])
    for side in ("consistent", "inconsistent"):
        video = batch[side]
        camera = batch["camera"]
        with_objects = model.surprise(video["frames"], video["mask"], camera, video["objects"])
        without = model.surprise(video["frames"], video["mask"], camera, None)
        assert torch.equal(with_objects, without)
    assert ObjectStateModel(**GEOMETRY_OFF).inputs_read() == frozenset({"objects"})


def test_mask_features_held_once_per_clip_train_as_the_masks_and_frames_do(tmp_path):
    """``train_fields: [mask_features, camera]``: each training clip's ``per_id`` measures,
    made once when the clips are loaded (``datamodules.resident``), give the loss the clip's
    mask and frames give, with no mask or frame held; a store that lacks them is refused."""
    from voe_lightning.data.store import generate_dataset, open_split
    from voe_lightning.datamodules.resident import MASK_FEATURES, resident_records

    generate_dataset(
        tmp_path, ["solidity"], train_examples=3, train_controls=1, val_pairs=0, test_pairs=0,
        generalization_pairs=0, workers=1, num_frames=8, height=32, width=32, progress=False,
        splits=("train",),
    )  # fmt: skip
    dataset = open_split(tmp_path, "solidity", "train")
    whole = resident_records(dataset, ["mask", "frames", "camera"], torch.device("cpu"))
    held = resident_records(dataset, [MASK_FEATURES, "camera"], torch.device("cpu"))
    assert set(held.keys()) == {MASK_FEATURES, "camera"} and len(held) == len(dataset)
    # the records' depth measures, where they hold them (stimuli version 13 on), for rgbd
    assert ("depth" in held[MASK_FEATURES].keys()) == ("depth" in dataset[0].keys())
    torch.manual_seed(0)
    model = ObjectStateModel(perception="masks", hidden_size=16, message_size=8, **GEOMETRY_OFF)
    model.hparams.withhold = 0.0  # no random spans: the two losses see the same clips
    torch.testing.assert_close(model.training_step(held, 0), model.training_step(whole, 0))
    with pytest.raises(KeyError, match=r"train_fields names \['lidar'\]"):
        resident_records(dataset, [MASK_FEATURES, "lidar"], torch.device("cpu"))

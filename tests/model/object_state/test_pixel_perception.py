"""The pixel rung of the learner (``perception: pixels``): each slot's state is the code its
encoder gives the frame masked to the slot's id, and nothing while hidden; no geometry, prior or
image box is accepted with it; the encoder learns first, alone, then only the rest learns."""

import pytest
import torch

from voe_lightning import specs
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.object_state.arguments import GEOMETRY_OFF
from voe_lightning.model.object_state.pixels import object_encoder, observe_pixels, paint_codes
from voe_lightning.model.object_state.state import observe
from voe_lightning.scenes import generate_clip

PIXELS = dict(perception="pixels", projection=False, **GEOMETRY_OFF)


def test_each_slot_reads_its_ids_code_and_nothing_while_hidden():
    torch.manual_seed(0)
    encoder = object_encoder(6, (specs.HEIGHT, specs.WIDTH))
    batch = generate_clip("containment", "example", seed=3)[None]
    observed = observe_pixels(encoder, batch["mask"], batch["frames"], batch["camera"])
    by_states = observe(batch["objects"], batch["camera"])
    assert torch.equal(observed.ids, by_states.ids)  # the tracker's slots, in its order
    assert torch.equal(observed.visible, by_states.visible)
    assert observed.visible.any(1).all() and not observed.visible.all()  # someone hides
    x = specs.to_model_input(batch["frames"])[0]  # [T, 3, H, W]
    for slot, object_id in enumerate(observed.ids[0].tolist()):
        alone = (batch["mask"][0] == object_id).float()[:, None]  # [T, 1, H, W]
        expected, _ = encoder.encode(x, alone)  # every frame, one at a time
        seen = observed.visible[0, :, slot]
        torch.testing.assert_close(observed.state[0, seen, slot], expected[seen, 0])
        assert (observed.state[0, ~seen, slot] == 0).all()
        area = alone.mean((1, 2, 3))
        torch.testing.assert_close(observed.fraction[0, :, slot], area)
    assert (observed.shape == 0).all()  # no shape label: a camera gives none


def test_geometry_priors_and_image_boxes_are_refused_with_pixels():
    with pytest.raises(
        ValueError, match="perception: pixels gives no 3D state and no image box.*projection: False"
    ):
        ObjectStateModel(perception="pixels", **GEOMETRY_OFF)  # projection defaults to true
    with pytest.raises(ValueError, match="floor: False"):
        ObjectStateModel(**{**PIXELS, "floor": True})
    with pytest.raises(ValueError, match="code_size >= 1.*got 0, 500, 4"):
        ObjectStateModel(**PIXELS, code_size=0)


def clips() -> torch.Tensor:
    return torch.stack(
        [generate_clip(c, "example", seed=s) for c in ("continuity", "solidity") for s in (0, 1)]
    )


def learn(model: ObjectStateModel, batch, steps: int, lr: float) -> tuple[list[float], set[str]]:
    """Adam steps of ``model.training_step``: the losses and the parameters given a gradient."""
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    losses, updated = [], set()
    for step in range(steps):
        optimizer.zero_grad()
        loss = model.training_step(batch, step)
        loss.backward()
        updated |= {name for name, p in model.named_parameters() if p.grad is not None}
        optimizer.step()
        losses.append(loss.item())
    return losses, updated


def test_the_encoder_learns_first_and_alone_then_the_dynamics_over_its_codes():
    torch.manual_seed(0)
    batch = clips()
    model = ObjectStateModel(**PIXELS, hidden_size=32, message_size=16, code_size=8)
    assert model.perception_stage  # global step 0 < perception_steps
    losses, updated = learn(model, batch, 20, lr=1e-3)
    assert max(losses[-3:]) < 0.8 * losses[0], losses  # the frames' reconstruction improves
    assert updated and all(name.startswith("encoder.") for name in updated)

    model.hparams.perception_steps = 0  # the second stage: the encoder frozen
    assert not model.perception_stage
    frozen = {k: v.clone() for k, v in model.encoder.state_dict().items()}
    losses, updated = learn(model, batch, 20, lr=3e-3)
    assert losses[-1] < losses[0] - 20, losses
    assert updated and not any(name.startswith("encoder.") for name in updated)
    assert all(torch.equal(v, model.encoder.state_dict()[k]) for k, v in frozen.items())
    with pytest.raises(ValueError, match="perception: pixels reads .* batch key 'mask'"):
        model.surprise(batch["frames"], camera=batch["camera"])


def test_what_it_expected_is_its_beliefs_decoded():
    torch.manual_seed(0)
    batch = clips()[:2]
    model = ObjectStateModel(**PIXELS, hidden_size=16, message_size=8, code_size=4)
    images = model.expected_frames(batch["frames"], batch["mask"], batch["camera"])
    assert images.shape == (2, specs.NUM_FRAMES, 3, specs.HEIGHT, specs.WIDTH)
    assert images.min() >= 0 and images.max() <= 1
    # nothing expected seen: the background alone, decoded
    codes, background = torch.randn(1, 2, 3, 4), torch.randn(1, 2, 4)
    alone, _ = model.encoder.decode(background.flatten(0, 1)[:, None])
    torch.testing.assert_close(
        paint_codes(model.encoder, codes, torch.zeros(1, 2, 3), background),
        alone[:, 0].view(1, 2, 3, specs.HEIGHT, specs.WIDTH),
    )

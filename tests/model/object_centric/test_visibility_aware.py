"""The visibility-aware object-centric model (``ObjectCentricModel(surprise="likelihood")``)
and the PLATO-style pixel-space surprise (``surprise_space="pixels"``): shapes, the
likelihood's terms, a hidden ball tracked through occlusion after training on scripted pixel
clips and a vanishing that surprises it; in pixel space, a screen that changes colour."""

import pytest
import torch
from tensordict import TensorDict

from voe_lightning.model import ObjectCentricModel
from voe_lightning.model.object_centric.code_likelihood import TERMS, excess_surprisal, frame_terms

HEIGHT, WIDTH, FRAMES = 16, 20, 11
BALL, SCREEN = 1, 2  # mask ids
TINY = dict(
    image_size=(HEIGHT, WIDTH),
    num_slots=2,
    code_size=6,
    encoder_channels=(8, 8),
    state_size=24,
    relation_sizes=(24,),
    node_sizes=(24,),
    relation_size=24,
    use_camera=False,
    perception_frames=4,
    learning_rate=3e-3,
    code_loss_weight=0.1,
)


def scripted_clips(count: int, seed: int, change: str = "none") -> TensorDict:
    """Clips of a red 2 x 2 ball moving right at 1.5 px a frame, from a random start, behind a
    blue screen 6 px wide (in front of it): while behind, the ball's pixels are the screen's and
    its mask id is absent. ``change``: ``none`` (it comes out the other side), ``vanish``
    (never seen again once hidden) or ``recolour`` (the screen turns yellow once the ball is
    hidden); the same clip up to then."""
    generator = torch.Generator().manual_seed(seed)
    start = 1.5 * torch.rand(count, generator=generator)
    speed = torch.full((count,), 1.5)
    screen = torch.full((count,), 4)
    time = torch.arange(FRAMES, dtype=torch.float32)
    left = (start[:, None] + speed[:, None] * time).round().long()  # [N, T]
    columns = torch.arange(WIDTH)
    ball = (columns >= left[..., None]) & (columns < left[..., None] + 2)  # [N, T, W]
    cover = (columns >= screen[:, None]) & (columns < screen[:, None] + 6)  # [N, W]
    ball = ball & ~cover[:, None]
    behind = (~ball.any(-1) & (left >= screen[:, None])).cummax(dim=1).values  # [N, T]
    if change == "vanish":
        ball = ball & ~behind[..., None]
    mask = torch.zeros(count, FRAMES, HEIGHT, WIDTH, dtype=torch.uint8)
    mask[:, :, 7:9] = torch.where(ball, BALL, 0)[:, :, None].to(torch.uint8)
    mask[cover[:, None, None].expand(-1, FRAMES, HEIGHT, -1)] = SCREEN
    colours = torch.tensor(
        [[0, 0, 0], [230, 30, 30], [40, 40, 220], [220, 220, 40]], dtype=torch.uint8
    )
    painted = mask.long()
    if change == "recolour":
        painted = torch.where((painted == SCREEN) & behind[..., None, None], 3, painted)
    return TensorDict(
        {"frames": colours[painted], "mask": mask, "seed": torch.arange(count) + 1000 * seed},
        batch_size=[count],
    )


def _model(**overrides) -> ObjectCentricModel:
    torch.manual_seed(0)
    model = ObjectCentricModel(**{**TINY, "surprise": "likelihood", **overrides})
    model.log = lambda *args, **kwargs: None
    return model


def _train(model: ObjectCentricModel, perception: int, dynamics: int) -> ObjectCentricModel:
    """``perception`` steps of stage one, then ``dynamics`` steps of stage two, on fresh
    physical clips each step."""
    optimizer = model.configure_optimizers()
    model.train()
    for step in range(perception + dynamics):
        model.hparams.perception_steps = perception - step  # > 0: stage one
        loss = model.training_step(scripted_clips(8, seed=100 + step), step)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return model.eval()


@pytest.fixture(scope="module")
def trained() -> tuple[ObjectCentricModel, ObjectCentricModel]:
    """The same visibility-aware model untrained and after a short training (perception 100
    steps, dynamics 500, of 8 clips each) on physical clips only."""
    untrained = _model().eval()
    model = _model()
    model.load_state_dict(untrained.state_dict())
    return untrained, _train(model, 100, 500)


def test_the_scripted_ball_hides_behind_the_screen_and_comes_out():
    clips, vanish = scripted_clips(8, seed=1), scripted_clips(8, seed=1, change="vanish")
    seen = (clips["mask"] == BALL).flatten(2).any(-1)  # [N, T]
    gone = (vanish["mask"] == BALL).flatten(2).any(-1)
    hidden_then_seen = ~seen[:, 1:-1] & seen[:, 2:]
    assert bool(seen[:, 0].all()) and bool(hidden_then_seen.any(-1).all())
    first = (seen != gone).float().argmax(-1)  # the first frame the two differ
    for index in range(8):  # the same clip up to the reappearance, never seen again after
        assert torch.equal(
            clips["frames"][index, : first[index]], vanish["frames"][index, : first[index]]
        )
        assert not gone[index, first[index] :].any()


def test_shapes_terms_and_refusals():
    clips = scripted_clips(3, seed=2)
    for space in ("codes", "pixels"):
        model = _model(surprise_space=space).eval()
        surprise = model.surprise(clips["frames"], clips["mask"])
        assert surprise.shape == (3, FRAMES) and bool((surprise[:, 0] == 0).all())
        assert bool((surprise >= 0).all()) and bool(torch.isfinite(surprise).all())
    expected = model.expected_frames(clips["frames"], clips["mask"])
    assert expected.shape == (3, FRAMES, 3, HEIGHT, WIDTH)
    assert 0 <= expected.min() <= expected.max() <= 1
    courses = model.trajectories(clips["frames"], clips["mask"])
    assert courses["predicted"].shape == (3, FRAMES, 3 * 6)
    out = model._predict(clips["frames"], clips["mask"], None)
    prediction = out["prediction"]
    assert prediction["mean"].shape == prediction["log_std"].shape == (3, FRAMES, 3, 6)
    assert prediction["seen_logit"].shape == (3, FRAMES, 3)
    assert prediction["appear_logit"].shape == (3, FRAMES)
    terms = frame_terms(prediction, out["codes"], out["seen"], out["visible"])
    assert set(terms) == set(TERMS)
    # the ball is hidden at some frame: no code term there, a visibility term only
    hidden = ~out["visible"][:, 1:, BALL]
    assert bool((terms["code"][0][:, :, BALL][hidden] == 0).all())
    assert bool((terms["visibility"][0][:, :, BALL][hidden] > 0).all())
    model.hparams.surprise_space = "codes"
    torch.testing.assert_close(
        model.surprise(clips["frames"], clips["mask"])[:, 1:], excess_surprisal(terms)
    )
    with pytest.raises(ValueError, match="surprise must be 'squared_error' or 'likelihood'"):
        ObjectCentricModel(**TINY, surprise="kl")
    with pytest.raises(ValueError, match="surprise_space 'codes' or 'pixels'.*'frames'"):
        ObjectCentricModel(**TINY, surprise_space="frames")


def test_training_is_the_frames_negative_log_likelihood_and_only_the_dynamics_learn():
    model = _model()
    model.train()
    model.hparams.perception_steps = 0
    clips = scripted_clips(4, seed=3)
    loss = model.training_step(clips, 0)
    loss.backward()
    terms = model.dynamics_terms(clips)
    assert set(terms) == {"loss", *TERMS}
    weights = {"visibility": 1.0, "appear": 1.0, "code": 0.1, "newcomer_code": 0.1}
    torch.testing.assert_close(terms["loss"], sum(weights[name] * terms[name] for name in TERMS))
    assert all(p.grad is None for p in model.perception.parameters())
    assert all(p.grad is not None for p in model.dynamics.spread.parameters())
    assert all(p.grad is not None for p in model.dynamics.seen_logit.parameters())


def _reappearance(model: ObjectCentricModel, clips: TensorDict) -> tuple[float, float]:
    """Mean p(seen) of the ball at the frames it comes out from behind the screen, and its
    code's negative log-likelihood there."""
    with torch.no_grad():
        out = model._predict(clips["frames"], clips["mask"], None)
    seen = out["visible"][:, :, BALL]
    back = seen[:, 1:] & ~seen[:, :-1]  # [N, T - 1]: seen again at t + 1
    probability = torch.sigmoid(out["prediction"]["seen_logit"][:, :-1, BALL])[back]
    terms = frame_terms(out["prediction"], out["codes"], out["seen"], out["visible"])
    return float(probability.mean()), float(terms["code"][0][:, :, BALL][back].mean())


@pytest.mark.slow
def test_after_training_a_hidden_ball_is_expected_back_and_a_vanishing_surprises(trained):
    """Trained on physical clips only, the model expects the hidden ball to come out again,
    where the untrained one does not, and its code there is likelier; the same ball vanishing
    behind the screen is more surprising than coming out, pair by pair."""
    untrained, model = trained
    clips, vanish = scripted_clips(32, seed=7), scripted_clips(32, seed=7, change="vanish")
    before, after = _reappearance(untrained, clips), _reappearance(model, clips)
    assert after[0] > 0.6 and after[0] > before[0] + 0.15, (before, after)
    assert after[1] < before[1], (before, after)
    physical = model.surprise(clips["frames"], clips["mask"]).sum(-1)
    vanished = model.surprise(vanish["frames"], vanish["mask"]).sum(-1)
    assert (vanished > physical).float().mean() > 0.9, (physical, vanished)
    assert float((vanished - physical).mean()) > 2.0, (physical, vanished)


def test_pixel_space_surprise_is_the_decoded_prediction_against_the_frame(trained):
    """The PLATO-style pixel-space surprise: per frame, the squared error between the frame composed
    of the decoded predicted codes (``expected_frames``) and the frame seen; in a scripted
    case, the screen turning yellow while it hides the ball raises it, pair by pair."""
    _, model = trained
    for surprise in ("squared_error", "likelihood"):
        pixels = _model(surprise=surprise, surprise_space="pixels").eval()
        if surprise == "likelihood":
            pixels.load_state_dict(model.state_dict())
        clips = scripted_clips(4, seed=5)
        x = pixels._model_input(clips["frames"], pixels.image_size)
        error = (pixels.expected_frames(clips["frames"], clips["mask"]) - x).pow(2)
        error = error.sum(dim=(2, 3, 4))
        error[:, 0] = 0
        torch.testing.assert_close(pixels.surprise(clips["frames"], clips["mask"]), error)
    clips, recoloured = scripted_clips(32, seed=7), scripted_clips(32, seed=7, change="recolour")
    assert not torch.equal(clips["frames"], recoloured["frames"])
    assert torch.equal(clips["mask"], recoloured["mask"])
    physical = pixels.surprise(clips["frames"], clips["mask"]).sum(-1)
    changed = pixels.surprise(recoloured["frames"], recoloured["mask"]).sum(-1)
    assert (changed > physical).float().mean() > 0.9, (physical, changed)

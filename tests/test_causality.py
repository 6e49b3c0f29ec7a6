"""Causality is part of the model protocol (docs/architecture.md §7): a model's surprise at frame t
may depend only on the frames, masks, camera poses and object states up to t. Every
``SurpriseModel`` family the package ships runs through two checks: on generated probe pairs,
whose two videos are byte-identical through the manipulation frame, per-frame surprise is
identical there; and on a random video, truncating or altering everything after frame t leaves
surprise up to t unchanged. A family that failed could read the answer from the future (an id
that first appears later, a slot count, a normalisation over the whole video)."""

import importlib.util

import pytest
import torch
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.model import (
    CueScorer,
    ObjectCentricModel,
    ObjectFollower,
    ObjectStateModel,
    SurpriseModel,
    VRNNLRUModel,
)
from voe_lightning.model.base import video_inputs
from voe_lightning.model.scorers.cue_scorer import CUE_NAMES
from voe_lightning.model.scorers.followers import INPUTS, RULES
from voe_lightning.model.scorers.videomae import VideoMAEScorer
from voe_lightning.model.scorers.vjepa2 import VJEPA2Scorer
from voe_lightning.scenes import CONCEPTS, PROBE_VARIANTS, generate_probe

SIZE = 32
SEEDS = (0, 1)
#: "Identical": within 1e-6, absolute or relative (float32 resolves a surprise of 48 to 4e-6;
#: summing over another number of slots may move it by that much).
TOLERANCE = 1e-6
# float32: bf16 kernels may round identical rows of a batch apart (3e-8 on one pair here, on
# an AVX-512 EPYC), which is no information from the future but could pass 1e-6 elsewhere.
VRNN = dict(
    image_size=(SIZE, SIZE),
    latent_size=8,
    mlp_sizes=(16, 16),
    memory_slots=5,
    memory_slot_size=6,
    memory_read_heads=2,
    controller_size=12,
    encoder_blocks=3,
    encoder_channels=(4, 4, 8),
    encoder_mlp_size=20,
    precision="float32",
)
# Ten object slots: the generalization variants show up to nine objects in one video.
OBJECT_CENTRIC = dict(
    image_size=(SIZE, SIZE),
    num_slots=10,
    code_size=8,
    encoder_channels=(8, 8),
    state_size=16,
    relation_sizes=(16,),
    node_sizes=(16,),
    relation_size=16,
)

# Sixteen frames: the probes have fifteen (padded to the model's length).
VIDEOMAE = dict(
    image_size=SIZE,
    patch_size=8,
    num_frames=16,
    tubelet_size=2,
    hidden_size=16,
    num_hidden_layers=1,
    num_attention_heads=2,
    intermediate_size=32,
    decoder_num_attention_heads=2,
    decoder_hidden_size=16,
    decoder_num_hidden_layers=1,
    decoder_intermediate_size=32,
)
# Windows of 4 frames, 2 seen, sliding by 1: every frame from the fourth is scored.
VJEPA2 = dict(
    context_frames=2,
    window_frames=4,
    frame_step=1,
    window_stride=1,
    config=dict(
        crop_size=SIZE,
        patch_size=8,
        tubelet_size=2,
        hidden_size=24,
        num_attention_heads=2,
        num_hidden_layers=1,
        mlp_ratio=2.0,
        pred_hidden_size=12,
        pred_num_attention_heads=2,
        pred_num_hidden_layers=1,
        pred_mlp_ratio=2.0,
        pred_zero_init_mask_tokens=False,
        num_pooler_layers=1,
    ),
)

#: Every model family the package ships, untrained and tiny: one line adds a family.
#: The object-state learner's priors off (configs/learned_states.yaml) and its givens removed.
NO_PRIORS = dict(
    landing_component=False,
    pivot_landing=False,
)
NO_GIVENS = dict(sight_lines=False, floor=False, inertia=False, projection=False)
FAMILIES = [
    pytest.param(lambda: VRNNLRUModel(**VRNN), id="vrnn_lru"),
    pytest.param(lambda: ObjectCentricModel(**OBJECT_CENTRIC), id="object_centric"),
    pytest.param(lambda: ObjectCentricModel(**OBJECT_CENTRIC, object_free=True), id="object_free"),
    pytest.param(
        lambda: ObjectCentricModel(**OBJECT_CENTRIC, surprise_space="pixels"),
        id="object_centric_pixels",
    ),
    pytest.param(
        lambda: ObjectCentricModel(**OBJECT_CENTRIC, surprise="likelihood"), id="visibility_aware"
    ),
    pytest.param(
        lambda: ObjectCentricModel(
            **OBJECT_CENTRIC, surprise="likelihood", surprise_space="pixels"
        ),
        id="visibility_aware_pixels",
    ),
    pytest.param(
        lambda: ObjectCentricModel(**OBJECT_CENTRIC, object_free=True, surprise="likelihood"),
        id="object_free_likelihood",
    ),
    pytest.param(lambda: ObjectStateModel(hidden_size=16, message_size=8), id="object_state"),
    pytest.param(
        lambda: ObjectStateModel(
            hidden_size=16, message_size=8, components=3, pivot_landing=False, landing_change=False
        ),
        id="object_state_flat_landing",
    ),
    pytest.param(
        lambda: ObjectStateModel(hidden_size=16, message_size=8, components=1, **NO_PRIORS),
        id="object_state_no_priors",
    ),
    pytest.param(  # configs/learned_states.yaml's learner with its four givens removed too
        lambda: ObjectStateModel(hidden_size=16, message_size=8, **NO_PRIORS, **NO_GIVENS),
        id="object_state_nothing_given",
    ),
    pytest.param(  # ... and seeing learned from the states (configs/oracle_states_1000_steps.yaml)
        lambda: ObjectStateModel(
            hidden_size=16, message_size=8, **NO_PRIORS, **NO_GIVENS, visibility_from="states"
        ),
        id="object_state_nothing_given_seen_from_states",
    ),
    pytest.param(  # ... started with its heads at zero (zero_heads)
        lambda: ObjectStateModel(
            hidden_size=16,
            message_size=8,
            **NO_PRIORS,
            **NO_GIVENS,
            visibility_from="states",
            zero_heads=True,
        ),
        id="object_state_zero_heads",
    ),
    pytest.param(  # configs/learned_masks.yaml's learner: what the masks and frames show
        lambda: ObjectStateModel(
            perception="masks", hidden_size=16, message_size=8, **NO_PRIORS, **NO_GIVENS
        ),
        id="object_state_masks",
    ),
    pytest.param(  # configs/rgbd_15min.yaml's learner: the masks, frames and depth measures
        lambda: ObjectStateModel(
            perception="rgbd",
            hidden_size=16,
            message_size=8,
            **NO_PRIORS,
            **{**NO_GIVENS, "inertia": True},
        ),
        id="object_state_rgbd",
    ),
    pytest.param(  # configs/learned_pixels.yaml's learner: a learned code of each id's pixels
        lambda: ObjectStateModel(
            perception="pixels",
            frame_size=(SIZE, SIZE),
            hidden_size=16,
            message_size=8,
            code_size=4,
            **NO_PRIORS,
            **NO_GIVENS,
        ),
        id="object_state_pixels",
    ),
    *[pytest.param(lambda cue=cue: CueScorer(cue), id=f"cue_{cue}") for cue in CUE_NAMES],
    *[
        pytest.param(lambda r=rule, f=inputs: ObjectFollower(r, f), id=f"follower_{inputs}_{rule}")
        for rule in RULES
        for inputs in INPUTS
    ],
    pytest.param(
        lambda: VideoMAEScorer(config=VIDEOMAE),
        id="videomae",
        marks=pytest.mark.skipif(
            importlib.util.find_spec("transformers") is None,
            reason="VideoMAEScorer needs transformers",
        ),
    ),
    pytest.param(
        lambda: VJEPA2Scorer(**VJEPA2),
        id="vjepa2",
        marks=pytest.mark.skipif(
            importlib.util.find_spec("transformers") is None,
            reason="VJEPA2Scorer needs transformers",
        ),
    ),
]


def _build(family) -> SurpriseModel:
    """The family's model with fixed initial weights, in eval mode."""
    torch.manual_seed(0)
    return family().eval()


@pytest.fixture(scope="module")
def probes() -> TensorDict:
    """A probe pair of every concept, variant and seed of ``SEEDS``, stacked into one batch
    (the generator's records as they are: masks, camera, and object states when they carry
    them)."""
    records = [
        generate_probe(concept, variant, seed, height=SIZE, width=SIZE)
        for concept in CONCEPTS
        for variant in PROBE_VARIANTS[concept]
        for seed in SEEDS
    ]
    return torch.stack(records)


def _names(probes: TensorDict) -> list[str]:
    return [
        f"{specs.CONCEPTS[int(concept)]}/{specs.VARIANTS[int(variant)]}/seed {int(seed)}"
        for concept, variant, seed in zip(probes["concept"], probes["variant"], probes["seed"])
    ]


@pytest.mark.parametrize("family", FAMILIES)
def test_surprise_is_identical_through_the_manipulation_frame_of_every_probe(family, probes):
    """The probe step scores both videos of each pair from the pair's own masks, camera and
    object states; through the manipulation frame they are byte-identical, so is surprise."""
    out = _build(family).probe_step(probes)
    differences = {}
    for index, name in enumerate(_names(probes)):
        seen = int(probes["manipulation_frame"][index]) + 1
        for key in ("frames", "mask"):  # the premise: byte-identical videos through m
            assert torch.equal(
                probes["consistent", key][index, :seen], probes["inconsistent", key][index, :seen]
            ), (name, key)
        consistent = out["surprise_consistent"][index, :seen]
        inconsistent = out["surprise_inconsistent"][index, :seen]
        scale = torch.maximum(consistent.abs(), inconsistent.abs()).clamp(min=1)
        differences[name] = float(((consistent - inconsistent).abs() / scale).max())
    differ = [
        f"{name}: {difference:.3g}"
        for name, difference in differences.items()
        if difference > TOLERANCE
    ]
    assert not differ, (
        "surprise differs through the manipulation frame (relative to "
        "max(|surprise|, 1)): " + "; ".join(differ)
    )


B, T = 2, 6


def _random_video(seed: int) -> dict:
    """Random frames and camera poses, a mask whose object ids first appear at different
    frames (4 at frame 0, 9 at 1, 2 at 3 though smaller than the ids before it, 6 at 4),
    object states whose visible fraction follows the mask and depth measures where it shows
    an id."""
    generator = torch.Generator().manual_seed(seed)
    frames = torch.randint(0, 256, (B, T, SIZE, SIZE, 3), dtype=torch.uint8, generator=generator)
    mask = torch.zeros(B, T, SIZE, SIZE, dtype=torch.uint8)
    for row, (object_id, first) in enumerate(((4, 0), (9, 1), (2, 3), (6, 4))):
        for t in range(first, T):
            mask[:, t, 7 * row : 7 * row + 5, 3 + t : 11 + t] = object_id
    camera = torch.randn(B, T, 6, generator=generator)
    return {
        "frames": frames,
        "mask": mask,
        "camera": camera,
        "objects": _objects(mask, seed),
        "depth": _depth(mask, seed),
    }


def _depth(mask: torch.Tensor, seed: int) -> torch.Tensor:
    """Random depth measures (``specs.depth_spec``) [B, T, OBJECT_SLOTS, 3] for ``mask``,
    zero where it shows no pixel of an id."""
    generator = torch.Generator().manual_seed(seed)
    ids = torch.arange(specs.OBJECT_SLOTS, dtype=torch.uint8)
    shown = (mask[..., None] == ids).flatten(2, 3).any(dim=2)
    shown[..., 0] = False
    measures = torch.rand(*shown.shape, len(specs.DEPTH_MEASURES), generator=generator) + 1.0
    return measures * shown[..., None]


def _read_by(model, video: dict) -> dict:
    """``video``'s inputs as the probe pipeline hands them (``base.video_inputs``): the depth
    only to a model that reads it."""
    return {"frames": video["frames"], **video_inputs(video, read=model.inputs_read())}


def _objects(mask: torch.Tensor, seed: int) -> TensorDict:
    """Random object states (``specs.objects_spec``) for ``mask`` [B, T, H, W]: an id's
    visible fraction is its share of the frame's pixels, its shape 0 where it is not seen."""
    torch.manual_seed(seed)
    spec = specs.objects_spec(mask.shape[1])
    objects = spec.expand(mask.shape[0], *spec.shape).rand()
    ids = torch.arange(specs.OBJECT_SLOTS, dtype=torch.uint8)
    visible = (mask[..., None] == ids).float().mean(dim=(2, 3))  # [B, T, OBJECT_SLOTS]
    visible[..., 0] = 0
    objects["visible_fraction"] = visible
    objects["shape_label"] = torch.where(visible > 0, objects["shape_label"].clamp(min=1), 0)
    return objects


def _splice(value, t: int, other=None):
    """A tensor or object states [B, T, ...] up to frame t, then ``other``'s after it (none:
    cut there)."""

    def splice(mine: torch.Tensor, theirs: torch.Tensor | None = None) -> torch.Tensor:
        return (
            mine[:, : t + 1]
            if theirs is None
            else torch.cat([mine[:, : t + 1], theirs[:, t + 1 :]], dim=1)
        )

    if isinstance(value, TensorDict):
        return value.apply(splice, *(() if other is None else (other,)))
    return splice(value, other)


@pytest.mark.parametrize("family", FAMILIES)
def test_nothing_after_frame_t_changes_surprise_up_to_t(family):
    """For every frame t of a random video: cutting the video after t, or replacing its frames,
    masks (an object vanishes, a new id appears), camera poses and object states after t,
    leaves surprise[:, :t + 1] as it was."""
    model = _build(family)
    video = _random_video(0)
    other = _random_video(1)
    other["mask"] = torch.where(other["mask"] == 4, 13, other["mask"])  # id 4 gone, id 13 new
    other["objects"] = _objects(other["mask"], 1)
    other["depth"] = _depth(other["mask"], 1)
    surprise = model.surprise(**_read_by(model, video))
    for t in range(T - 1):
        cut = {name: _splice(value, t) for name, value in video.items()}
        altered = {name: _splice(value, t, other[name]) for name, value in video.items()}
        for name, changed in (("cut", cut), ("altered", altered)):
            torch.testing.assert_close(
                model.surprise(**_read_by(model, changed))[:, : t + 1],
                surprise[:, : t + 1],
                atol=TOLERANCE,
                rtol=TOLERANCE,
                msg=lambda message, name=name, t=t: f"{name} after frame {t}: {message}",
            )

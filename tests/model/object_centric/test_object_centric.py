"""The object-centric model after PLATO and its object-free twin: slots from masks, the two
training stages, slot symmetry, padding, refusals, parameter parity, and fit + test by CLI."""

import json

import pytest
import torch
from helpers.locations import REPO, TINY_CONFIG
from tensordict import TensorDict

from voe_lightning.cli import main
from voe_lightning.model import ObjectCentricModel, SurpriseModel
from voe_lightning.model.object_centric.model import SURPRISES
from voe_lightning.model.object_centric.slots import MAX_MASK_JUMP, centroid_moves, object_slots
from voe_lightning.scenes import (
    CLIP_KINDS_BY_CONCEPT,
    CONCEPTS,
    PROBE_VARIANTS,
    generate_clip,
    generate_probe,
)

TINY = dict(
    image_size=(32, 32),
    num_slots=4,
    code_size=8,
    encoder_channels=(8, 8),
    state_size=16,
    relation_sizes=(16,),
    node_sizes=(16,),
    relation_size=16,
)
B, T = 2, 5


def _model(**overrides) -> ObjectCentricModel:
    torch.manual_seed(0)
    return ObjectCentricModel(**{**TINY, **overrides}).eval()


def _video(ids=(3, 5), seed=0):
    """Random frames and a mask with a square per id, object 5 hidden in frame 2."""
    generator = torch.Generator().manual_seed(seed)
    frames = torch.randint(0, 256, (B, T, 32, 32, 3), dtype=torch.uint8, generator=generator)
    mask = torch.zeros(B, T, 32, 32, dtype=torch.uint8)
    for number, object_id in enumerate(ids):
        mask[:, :, 6 * number : 6 * number + 5, 2 + number : 12 + number] = object_id
    mask[:, 2][mask[:, 2] == 5] = 0
    camera = torch.randn(B, T, 6, generator=generator)
    return frames, mask, camera


def _batch(frames, mask, camera):
    return TensorDict(
        frames=frames, mask=mask, camera=camera, seed=torch.tensor([11, 12]), batch_size=[B]
    )


def test_slots_follow_ids_and_keep_an_occluded_object():
    _, mask, _ = _video()
    slots = object_slots(mask, num_slots=4)
    assert slots.ids[0].tolist() == [0, 3, 5, 0, 0]
    assert slots.seen[0].tolist() == [[True, True, True, False, False]] * T
    assert slots.masks[0, 2, 2].sum() == 0 and slots.masks[0, 1, 2].sum() > 0  # hidden, kept
    assert torch.equal(slots.masks.sum(2), torch.ones(B, T, 32, 32))  # a partition of pixels


def test_a_slot_is_created_when_its_id_is_first_seen():
    """An id first seen at frame 3 takes the next free slot then, though it is smaller than
    the ids seen before it, and counts as seen from frame 3 on only."""
    _, mask, _ = _video()
    mask[:, 3:, 26:31, 20:25] = 2
    slots = object_slots(mask, num_slots=4)
    assert slots.ids[0].tolist() == [0, 3, 5, 2, 0]
    assert slots.seen[0, :, 3].tolist() == [False] * 3 + [True] * (T - 3)
    assert not slots.seen[0, :, 4].any()


def test_shapes_and_each_stage_trains_only_its_networks():
    model = _model(perception_steps=1).train()
    frames, mask, camera = _video()
    assert model.surprise(frames, mask, camera).shape == (B, T)
    expected = model.expected_frames(frames, mask, camera)
    assert expected.shape == (B, T, 3, 32, 32) and 0 <= expected.min() <= expected.max() <= 1
    courses = model.trajectories(frames, mask, camera)
    assert {k: tuple(v.shape) for k, v in courses.items()} == {
        "codes": (B, T, 40),
        "predicted": (B, T, 40),
    }
    batch = _batch(frames, mask, camera)
    # Without a trainer global_step is 0: perception_steps 1 is stage one, 0 is stage two.
    for steps, trained, frozen in (
        (1, model.perception, model.dynamics),
        (0, model.dynamics, model.perception),
    ):
        model.zero_grad(set_to_none=True)
        model.hparams.perception_steps = steps
        model.training_step(batch, 0).backward()
        assert all(p.grad is not None for p in trained.parameters()), steps
        assert any(p.grad.abs().sum() > 0 for p in trained.parameters()), steps
        assert all(p.grad is None for p in frozen.parameters()), steps
    assert not model.perception.training  # frozen in eval mode in the dynamics stage


def test_the_open_choices_train_and_score():
    """The arguments the paper leaves open: a plain autoencoder (no KL, deterministic codes),
    surprise in pixel space (the pixel error of the decoded prediction) and no camera input."""
    frames, mask, camera = _video()
    batch = _batch(frames, mask, camera)
    for variational in (True, False):
        model = _model(variational=variational, perception_steps=1, perception_frames=None)
        first, second = (model.train().perception_terms(batch) for _ in range(2))
        assert torch.isfinite(first["loss"]) and (first["kl"] > 0) == variational
        same = torch.isclose(first["reconstruction"], second["reconstruction"], rtol=1e-5)
        assert bool(same) != variational  # sampled codes only in the VAE
    codes_only, in_pixels = _model(), _model(surprise_space="pixels")
    in_pixels.load_state_dict(codes_only.state_dict())
    expected = codes_only.expected_frames(frames, mask, camera)
    x = codes_only._model_input(frames, codes_only.image_size)
    pixels = (expected - x).pow(2).sum(dim=(2, 3, 4))
    pixels[:, 0] = 0
    torch.testing.assert_close(in_pixels.surprise(frames, mask, camera), pixels)
    assert "pixel" in in_pixels.SURPRISE and "pixel" not in codes_only.SURPRISE
    blind = _model(use_camera=False, perception_steps=0).train()
    assert blind.surprise(frames, mask).shape == (B, T)
    del batch["camera"]
    blind.training_step(batch, 0).backward()
    assert all(p.grad is not None for p in blind.dynamics.parameters())


def _permuted(model, frames, mask, camera, order):
    """Predicted codes and surprise with the object ids relabelled so slots take ``order``."""
    relabel = torch.arange(256, dtype=torch.uint8)
    old = [3, 5, 7]
    for slot, target in enumerate(order):
        relabel[old[target]] = old[slot]
    relabeled = relabel[mask.long()]
    out = model._predict(frames, relabeled, camera)
    return out["predicted"], model.surprise(frames, relabeled, camera)


def test_permuting_the_object_slots_permutes_predictions_and_keeps_surprise():
    model = _model()
    frames, mask, camera = _video(ids=(3, 5, 7))
    predicted, surprise = _permuted(model, frames, mask, camera, [0, 1, 2])
    swapped, swapped_surprise = _permuted(model, frames, mask, camera, [2, 0, 1])
    # Slot 1 + k holds the object that held slot 1 + order[k] before.
    torch.testing.assert_close(swapped[:, :, 1:4], predicted[:, :, [3, 1, 2]], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(swapped_surprise, surprise, atol=1e-4, rtol=1e-5)
    assert surprise[:, 1:].gt(0).all() and surprise[:, 0].eq(0).all()


def test_padding_slots_change_nothing():
    frames, mask, camera = _video()
    few, many = _model(num_slots=2), _model(num_slots=6)
    many.load_state_dict(few.state_dict())  # the same weights: slots are not parameters
    out_few = few._predict(frames, mask, camera)
    out_many = many._predict(frames, mask, camera)
    torch.testing.assert_close(
        out_many["predicted"][:, :, :3], out_few["predicted"], atol=1e-5, rtol=1e-5
    )
    torch.testing.assert_close(
        many.surprise(frames, mask, camera),
        few.surprise(frames, mask, camera),
        atol=1e-4,
        rtol=1e-5,
    )


def test_bad_inputs_are_refused_naming_the_video():
    model = _model(num_slots=1)
    frames, mask, camera = _video()
    batch = _batch(frames, mask, camera)
    with pytest.raises(
        ValueError,
        match=r"video 0 of the batch \(seed 11\) shows 2 objects "
        r"\(mask ids \[3, 5\]\), more than num_slots=1",
    ):
        model.training_step(batch, 0)
    del batch["mask"]
    with pytest.raises(ValueError, match=r"needs each video's object-id mask .*seed 11"):
        model.training_step(batch, 0)
    with pytest.raises(ValueError, match="needs each video's object-id mask"):
        model.surprise(frames, None, camera)
    with pytest.raises(ValueError, match="no video of the batch shows an object"):
        _model().surprise(frames, torch.zeros_like(mask), camera)
    with pytest.raises(ValueError, match="use_camera is set but no camera pose"):
        _model().surprise(frames, mask)
    probes = TensorDict(
        consistent=TensorDict(frames=frames, mask=mask, batch_size=[B]),
        inconsistent=TensorDict(frames=frames, batch_size=[B]),
        camera=camera,
        seed=torch.tensor([21, 22]),
        concept=torch.zeros(B),
        variant=torch.zeros(B),
        manipulation_frame=torch.ones(B),
        batch_size=[B],
    )
    with pytest.raises(ValueError, match=r"seed 21"):
        _model().probe_step(probes)


def test_a_mask_id_that_jumps_between_frames_is_refused_naming_the_video():
    _, mask, _ = _video()
    jumped = mask.clone()
    jumped[1, 3:][jumped[1, 3:] == 3] = 0
    jumped[1, 3:, 26:31, 20:30] = 3  # id 3 teleports to the far corner at frame 3
    with pytest.raises(
        ValueError,
        match=r"video 1 of the batch \(seed 12\): mask id 3 jumps "
        r"0\.[5-9]\d of the frame diagonal between frames 2 "
        r"and 3",
    ):
        object_slots(jumped, num_slots=4, seeds=torch.tensor([11, 12]))
    frames, _, camera = _video()
    with pytest.raises(ValueError, match="raise max_mask_jump where objects really move"):
        _model().surprise(frames, jumped, camera)
    assert _model(max_mask_jump=None).surprise(frames, jumped, camera).shape == (B, T)
    with pytest.raises(ValueError, match="max_mask_jump must be > 0 or None"):
        _model(max_mask_jump=0.0)
    # Ids numbered per frame (a new id in every frame) read as more objects than slots: the
    # error says that no frame has that many, so the ids change between frames.
    renumbered = mask.clone()
    for t in range(T):
        renumbered[:, t][renumbered[:, t] == 3] = 10 + t
    with pytest.raises(
        ValueError,
        match=r"shows 6 objects .* no frame shows more than 2 at once: "
        r"if the ids number each frame's objects",
    ):
        object_slots(renumbered, num_slots=4)
    with pytest.raises(ValueError, match=r"more than num_slots=1; raise num_slots"):
        object_slots(mask, num_slots=1)


def test_a_sample_of_a_clips_frames_is_no_jump():
    """Stage one trains on a random sample of each clip's frames: an object that moves steadily
    lies far apart in two sampled frames, which is no jump (the whole clip is checked)."""
    frames, mask, camera = _video()
    moving = torch.zeros_like(mask)
    for t in range(T):
        moving[:, t, 2:7, 2 + 6 * t : 7 + 6 * t] = 3  # 6 pixels a frame: 0.13 of the diagonal
    with pytest.raises(ValueError, match="mask id 3 jumps 0.5"):
        object_slots(moving[:, [0, 4]], num_slots=4)
    object_slots(moving[:, [0, 4]], num_slots=4, max_jump=None)
    object_slots(moving[:, [0, 4]], num_slots=4, max_jump=0.6)
    model = _model(perception_steps=1, perception_frames=2).train()
    batch = _batch(frames, moving, camera)
    torch.manual_seed(0)
    for _ in range(20):  # some of these samples take frames 0 and 4
        assert torch.isfinite(model.training_step(batch, 0))


def _generated_videos(seeds=range(2)):
    for concept in CONCEPTS:
        for seed in seeds:
            for kind in CLIP_KINDS_BY_CONCEPT[concept]:
                yield f"{concept}/{kind}/{seed}", generate_clip(concept, kind, seed)["mask"]
            for variant in PROBE_VARIANTS[concept]:
                record = generate_probe(concept, variant, seed)
                for side in ("consistent", "inconsistent"):
                    yield f"{concept}/{variant}/{side}/{seed}", record[side]["mask"]


def test_the_generators_masks_follow_one_object_per_id():
    """Every clip kind and probe variant passes the jump check with room to spare (its
    largest centroid move is well under MAX_MASK_JUMP)."""
    for name, mask in _generated_videos():
        slots = object_slots(mask[None], num_slots=12)
        largest = float(centroid_moves(slots.masks[:, :, 1:] > 0).max())
        assert largest < 0.8 * MAX_MASK_JUMP, (name, largest)


def test_object_free_twin_needs_no_mask_and_matches_the_parameter_count():
    sizes = dict(
        image_size=(64, 64),
        num_slots=10,
        code_size=32,
        encoder_channels=(16, 32, 32, 64),
        state_size=64,
        relation_sizes=(64,),
        node_sizes=(64,),
        relation_size=64,
    )
    objects, twin = _model(**sizes), _model(**sizes, object_free=True)
    count = [sum(p.numel() for p in m.parameters()) for m in (objects, twin)]
    assert abs(count[1] - count[0]) <= 0.1 * count[0], count
    assert twin.code_size > objects.code_size  # no interaction network: a larger code
    frames, _, camera = _video()
    assert _model(object_free=True).surprise(frames, None, camera).shape == (B, T)


def test_checkpoint_of_the_twin_is_refused_naming_the_difference():
    model, twin = _model(), _model(object_free=True)
    checkpoint = {"hyper_parameters": dict(twin.hparams), "state_dict": twin.state_dict()}
    with pytest.raises(ValueError, match="object_free: checkpoint True, config False"):
        model.on_load_checkpoint(checkpoint)
    assert isinstance(model, SurpriseModel)


@pytest.mark.parametrize(
    "object_free, surprise",
    [(False, "squared_error"), (True, "squared_error"), (False, "likelihood")],
)
def test_fit_both_stages_then_test_through_the_cli(tmp_path, monkeypatch, object_free, surprise):
    monkeypatch.chdir(tmp_path)
    model = [
        "--model",
        "voe_lightning.model.ObjectCentricModel",
        "--model.image_size=[32, 32]",
        "--model.num_slots=4",
        "--model.code_size=8",
        "--model.encoder_channels=[8, 8]",
        "--model.state_size=16",
        "--model.relation_sizes=[16]",
        "--model.node_sizes=[16]",
        "--model.relation_size=16",
        "--model.perception_steps=1",
        f"--model.object_free={object_free}",
        f"--model.surprise={surprise}",
    ]
    main(["fit", "--config", TINY_CONFIG, *model, "--trainer.logger.init_args.name=oc"])
    run = tmp_path / "runs" / "oc" / "version_0"
    checkpoint = torch.load(run / "checkpoints" / "last.ckpt", weights_only=True)
    assert checkpoint["global_step"] == 2  # one perception step, one dynamics step
    assert checkpoint["hyper_parameters"]["training_frames"] == 8
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            *model,
            "--trainer.logger.init_args.name=oc",
            "--ckpt_path",
            str(run / "checkpoints" / "last.ckpt"),
        ]
    )
    summary = json.loads((run / "voe_report" / "summary.json").read_text())
    assert summary["video_surprise"] == f"sum over frames of {SURPRISES[(surprise, 'codes')]}"
    assert "object codes" in (run / "voe_report" / "summary.md").read_text()
    rows = summary["rows"]
    assert {(r["concept"], r["variant"], r["n"]) for r in rows} == {
        ("object_persistence", "standard", 3),
        ("object_persistence", "counterbalanced", 3),
        ("object_persistence", "pooled", 6),
        ("object_persistence", "quadruplet", 3),
    }
    assert (run / "voe_report" / "predictions_object_persistence.png").is_file()


def test_the_object_free_twin_is_scored_on_intphys_by_the_benchmark_configs(tmp_path, monkeypatch):
    """configs/intphys_dev.yaml tests an object-free checkpoint, its model class coming from the
    checkpoint, and `predict` writes its answer.txt; IntPhys has neither masks nor camera poses,
    so this is the twin (without camera input) that can be scored there."""
    from helpers.intphys import FRAMES, make_intphys

    monkeypatch.chdir(tmp_path)
    model = [
        "--model",
        "voe_lightning.model.ObjectCentricModel",
        "--model.image_size=[32, 32]",
        "--model.code_size=8",
        "--model.encoder_channels=[8, 8]",
        "--model.state_size=16",
        "--model.relation_sizes=[16]",
        "--model.node_sizes=[16]",
        "--model.relation_size=16",
        "--model.perception_steps=1",
        "--model.object_free=true",
        "--model.use_camera=false",
    ]  # IntPhys has no camera poses
    main(["fit", "--config", TINY_CONFIG, *model, "--trainer.logger.init_args.name=twin"])
    run = tmp_path / "runs" / "twin" / "version_0"
    checkpoint = str(run / "checkpoints" / "last.ckpt")
    configs = REPO / "configs"
    data = [
        "--data.init_args.root",
        str(tmp_path / "intphys"),
        "--data.init_args.frames_per_movie",
        str(FRAMES),
        "--data.init_args.num_workers",
        "0",
        "--data.init_args.cache_dir",
        "null",
    ]
    make_intphys(tmp_path / "intphys", "dev", labelled=True)
    cli = main(
        ["test", "--config", str(configs / "intphys_dev.yaml"), "--ckpt_path", checkpoint, *data]
    )
    assert isinstance(cli.model, ObjectCentricModel) and cli.model.hparams.object_free
    [report] = run.glob("intphys_dev-*/voe_report")  # the benchmark's own folder in the run
    metrics = json.loads((report / "benchmark_metrics.json").read_text())
    assert metrics  # IntPhys' own error rates of this checkpoint
    make_intphys(tmp_path / "intphys", "test", labelled=False)
    main(
        [
            "predict",
            "--config",
            str(configs / "intphys_test.yaml"),
            "--ckpt_path",
            checkpoint,
            *data,
        ]
    )
    lines = (tmp_path / "answer.txt").read_text().splitlines()
    assert len(lines) == 3 * 4 and all(0.0 <= float(line.split()[1]) <= 1.0 for line in lines)


def test_configs_build_models_of_matching_size(monkeypatch):
    from helpers.configs import compose

    monkeypatch.chdir(REPO)
    counts = {}
    for name, configs in (
        ("object_centric", ("base", "object_centric")),
        ("object_free", ("base", "object_free")),
        ("physical_concepts_object_centric", ("base", "physical_concepts_object_centric")),
    ):
        model = compose(*configs)["model"]
        assert model["class_path"] == "voe_lightning.model.ObjectCentricModel"
        built = ObjectCentricModel(**model["init_args"])
        counts[name] = sum(p.numel() for p in built.parameters())
    assert abs(counts["object_free"] - counts["object_centric"]) <= 0.1 * counts["object_centric"]


def test_fit_and_test_on_physical_concepts_freeform_and_probes(tmp_path, monkeypatch):
    """configs/physical_concepts_object_centric.yaml's path on a tiny Physical Concepts
    dataset in the released layout: train on freeform clips (masks and camera poses from the
    records), then test on the probe quadruplets with the benchmark's own metrics."""
    from helpers.physical_concepts import make_dataset

    monkeypatch.chdir(tmp_path)
    root = make_dataset(tmp_path / "physical_concepts")
    configs = REPO / "configs"
    arguments = [
        *(
            word
            for name in ("base", "physical_concepts_object_centric")
            for word in ("--config", str(configs / f"{name}.yaml"))
        ),
        "--trainer.max_steps=2",
        "--trainer.val_check_interval=2",
        "--trainer.logger.init_args.name=pc",
        "--model.image_size=[32, 32]",
        "--model.num_slots=4",
        "--model.code_size=8",
        "--model.encoder_channels=[8, 8]",
        "--model.state_size=16",
        "--model.relation_sizes=[16]",
        "--model.node_sizes=[16]",
        "--model.relation_size=16",
        "--model.perception_steps=1",
        f"--data.root={root}",
        "--data.concepts=[continuity, solidity]",
        "--data.num_frames=5",
        "--data.height=32",
        "--data.width=32",
        "--data.batch_size=2",
        "--data.probe_batch_size=4",
        "--data.val_quadruplets_per_concept=1",
        "--data.num_workers=0",
        f"--data.cache_dir={tmp_path / 'cache'}",
    ]
    main(["fit", *arguments])
    run = tmp_path / "runs" / "pc" / "version_0"
    assert torch.load(run / "checkpoints" / "last.ckpt", weights_only=True)["global_step"] == 2
    main(["test", *arguments, "--ckpt_path", str(run / "checkpoints" / "last.ckpt")])
    report = next(run.rglob("voe_report"))
    rows = json.loads((report / "summary.json").read_text())["rows"]
    assert {row["concept"] for row in rows} == {"continuity", "solidity"}
    # 2 shards x 2 quadruplets a concept: each half's 4 pairs, pooled 8, the quadruplet test's 4
    sizes = {(row["concept"], row["variant"]): row["n"] for row in rows}
    for concept in ("continuity", "solidity"):
        assert {
            v: sizes[(concept, v)] for v in ("standard", "counterbalanced", "pooled", "quadruplet")
        } == {"standard": 4, "counterbalanced": 4, "pooled": 8, "quadruplet": 4}
    metrics = json.loads((report / "benchmark_metrics.json").read_text())["metrics"]
    assert {"absolute_error_rate", "auroc"} <= metrics["solidity"]["all"].keys()


def test_a_model_missing_part_of_the_contract_cannot_be_built():
    class Incomplete(SurpriseModel):
        def surprise(self, frames, mask=None, camera=None):
            return frames.new_zeros(frames.shape[:2], dtype=torch.float32)

    with pytest.raises(TypeError, match="expected_frames"):
        Incomplete()

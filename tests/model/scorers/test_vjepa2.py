"""The V-JEPA 2 scorer (transformers' VJEPA2Model, tiny random configuration) follows the
published intuitive-physics protocol: the window arithmetic (frame step, sliding windows,
surprise at each window's last frame) against a hand computation, each window's value the L1
error of the predictor's features from the context alone against the layer-normed encoder
features of the whole window, causal and frozen; a folder saved with save_pretrained loads
without the network, and ``test`` scores it on our probes with no checkpoint. The causality
protocol test (tests/test_causality.py) runs it with every other family."""

import pytest
import torch
import torch.nn.functional as F

pytest.importorskip("transformers")

from helpers.locations import TINY_CONFIG

from voe_lightning import specs  # noqa: E402
from voe_lightning.cli import main  # noqa: E402
from voe_lightning.model.scorers.vjepa2 import VJEPA2Scorer, window_ends  # noqa: E402

#: A tiny V-JEPA 2 (random mask tokens, so the predictor's outputs differ by position).
CONFIG = dict(
    crop_size=32,
    patch_size=8,
    frames_per_clip=4,
    tubelet_size=2,
    hidden_size=24,
    num_attention_heads=2,
    num_hidden_layers=1,
    mlp_ratio=2.0,
    pred_hidden_size=12,
    pred_num_attention_heads=2,
    pred_num_hidden_layers=1,
    pred_mlp_ratio=2.0,
    pred_num_mask_tokens=2,
    pred_zero_init_mask_tokens=False,
    num_pooler_layers=1,
)
#: Windows of 4 subsampled frames, the first 2 seen, every 2nd frame, starting every 2.
WINDOWS = dict(context_frames=2, window_frames=4, frame_step=2, window_stride=2)


def scorer(**overrides) -> VJEPA2Scorer:
    torch.manual_seed(0)
    return VJEPA2Scorer(config=CONFIG, **{**WINDOWS, **overrides})


def video(seed=0, frames=17, size=32):
    generator = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (2, frames, size, size, 3), dtype=torch.uint8, generator=generator)


def test_windows_by_hand():
    # 17 frames every 2nd: frames 0, 2, ..., 16 (9 subsampled); windows of 4 from subsampled
    # 0, 2, 4 (6 would need 6..9); each ends at subsampled 3, 5, 7 = video frames 6, 10, 14
    assert window_ends(9, 4, 2, 2) == [(0, 6), (2, 10), (4, 14)]
    assert window_ends(3, 4, 2, 2) == []  # shorter than one window
    assert window_ends(6, 4, 1, 1) == [(0, 3), (1, 4), (2, 5)]


def test_surprise_is_each_windows_l1_error_at_its_last_frame():
    model = scorer()
    frames = video()
    surprise = model.surprise(frames)
    assert surprise.shape == (2, 17) and surprise.dtype == torch.float32
    scored = [6, 10, 14]
    assert (surprise[:, scored] > 0).all()
    assert (surprise[:, [t for t in range(17) if t not in scored]] == 0).all()
    # the window ending at frame 10: video frames 4, 6 (context) and 8, 10 (predicted)
    x = (specs.to_model_input(frames)[:, [4, 6, 8, 10]] - model.mean) / model.std
    network = model.model
    context = network.encoder(pixel_values_videos=x[:, :2]).last_hidden_state  # 1 tubelet
    whole = network.get_vision_features(x)  # 2 tubelets of 16 patches
    positions = torch.arange(32).expand(2, -1)
    predicted = network.predictor(
        encoder_hidden_states=context,
        context_mask=[positions[:, :16]],
        target_mask=[positions[:, 16:]],
    ).last_hidden_state
    expected = (predicted - F.layer_norm(whole, (24,))[:, 16:]).abs().mean(dim=(1, 2))
    torch.testing.assert_close(surprise[:, 10], expected)


def test_a_window_reads_its_own_frames_and_nothing_later():
    model = scorer()
    frames, other = video(0), video(1)
    surprise = model.surprise(frames)
    early = frames.clone()
    early[:, :4] = other[:, :4]  # before the window ending at 10 (it starts at frame 4)
    changed = model.surprise(early)
    assert torch.equal(changed[:, [10, 14]], surprise[:, [10, 14]])
    assert not torch.equal(changed[:, 6], surprise[:, 6])
    for t in range(16):  # frames after t change nothing up to t; a cut video scores as far
        spliced = torch.cat([frames[:, : t + 1], other[:, t + 1 :]], dim=1)
        torch.testing.assert_close(model.surprise(spliced)[:, : t + 1], surprise[:, : t + 1])
        torch.testing.assert_close(model.surprise(frames[:, : t + 1]), surprise[:, : t + 1])


def test_frozen_resized_and_swept_over_context_length():
    model = scorer()
    assert not any(p.requires_grad for p in model.parameters())
    assert tuple(model.hparams.image_size) == (32, 32)
    model.train()
    assert not model.model.training
    assert model.surprise(video(size=64)).shape == (2, 17)  # resized to the crop size
    sweep = model.surprise_per_context(video(), [2])
    assert list(sweep) == [2] and torch.equal(sweep[2], model.surprise(video()))
    longer = scorer(window_frames=6, frame_step=1, window_stride=1)
    swept = longer.surprise_per_context(video(frames=8), [2, 4])
    assert not torch.equal(swept[2], swept[4]) and (swept[4][:, :5] == 0).all()
    assert longer.expected_frames(video(frames=8)).shape == (2, 8, 3, 32, 32)


@pytest.mark.parametrize(
    "overrides, message",
    [
        (dict(context_frames=4), r"context_frames must be in 1..window_frames - 1 = 3, got 4"),
        (dict(context_frames=1), r"context_frames 1 is not a multiple of the model's tubelet_size"),
        (dict(window_frames=5, context_frames=2), r"window_frames 5 is not a multiple"),
        (dict(frame_step=0), r"frame_step must be at least 1, got 0"),
    ],
)
def test_window_settings_the_protocol_cannot_use_are_refused(overrides, message):
    with pytest.raises(ValueError, match=message):
        scorer(**overrides)


def test_a_saved_model_loads_from_its_local_folder(tmp_path):
    built = scorer()
    built.model.save_pretrained(tmp_path / "vjepa2")
    loaded = VJEPA2Scorer(pretrained=str(tmp_path / "vjepa2"), **WINDOWS)
    assert torch.equal(loaded.surprise(video()), built.surprise(video()))
    with pytest.raises(ValueError, match=r"either pretrained \(a local folder\) or config"):
        VJEPA2Scorer(context_frames=2)


def test_test_on_our_probes_runs_without_a_checkpoint(tmp_path, monkeypatch):
    scorer().model.save_pretrained(tmp_path / "vjepa2")
    monkeypatch.chdir(tmp_path)
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--model",
            "voe_lightning.model.VJEPA2Scorer",
            "--model.init_args.pretrained",
            str(tmp_path / "vjepa2"),
            "--model.init_args.context_frames",
            "2",
            "--model.init_args.window_frames",
            "4",
            "--model.init_args.frame_step",
            "1",
            "--trainer.enable_progress_bar",
            "false",
        ]
    )
    assert (tmp_path / "runs" / "tiny" / "version_0" / "voe_report" / "summary.json").is_file()

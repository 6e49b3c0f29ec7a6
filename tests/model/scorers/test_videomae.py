"""The VideoMAE adapter (transformers' VideoMAEForPreTraining, tiny random configuration):
its reconstruction targets are the ones the library's own loss uses, surprise is causal and
shaped per frame, a folder saved with save_pretrained loads without the network, and ``test``
scores it on our probes with no checkpoint."""

import pytest
import torch

pytest.importorskip("transformers")

from helpers.locations import TINY_CONFIG

from voe_lightning.cli import main  # noqa: E402
from voe_lightning.model.scorers.videomae import VideoMAEScorer  # noqa: E402

CONFIG = dict(
    image_size=32,
    patch_size=8,
    num_frames=6,
    tubelet_size=2,
    hidden_size=16,
    num_hidden_layers=1,
    num_attention_heads=2,
    intermediate_size=32,
    decoder_num_attention_heads=2,
    decoder_hidden_size=16,
    decoder_num_hidden_layers=1,
    decoder_intermediate_size=32,
    norm_pix_loss=False,
)


def video(seed=0, frames=6):
    generator = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (2, frames, 32, 32, 3), dtype=torch.uint8, generator=generator)


@pytest.mark.parametrize("norm_pix_loss", [False, True])
def test_targets_are_the_ones_the_library_loss_uses(norm_pix_loss):
    torch.manual_seed(0)
    scorer = VideoMAEScorer(config={**CONFIG, "norm_pix_loss": norm_pix_loss})
    x = scorer._padded(video())
    per = 16  # (32 / 8)^2 patches per tubelet
    masked = (torch.arange(3 * per) >= per).expand(2, -1)
    output = scorer.model(pixel_values=(x - scorer.mean) / scorer.std, bool_masked_pos=masked)
    targets = scorer.patches(x).flatten(1, 2)[masked].reshape(2, -1, output.logits.shape[-1])
    assert torch.allclose((output.logits - targets).square().mean(), output.loss, rtol=1e-5)


def test_surprise_is_per_frame_causal_and_frozen():
    torch.manual_seed(0)
    scorer = VideoMAEScorer(config=CONFIG)
    assert not any(p.requires_grad for p in scorer.parameters())
    assert tuple(scorer.hparams.image_size) == (32, 32) and scorer.hparams.training_frames == 6
    frames, other = video(0), video(1)
    surprise = scorer.surprise(frames)
    assert surprise.shape == (2, 6) and (surprise[:, [0, 1, 2, 4]] == 0).all()
    assert (surprise[:, [3, 5]] > 0).all()
    for t in range(5):  # frames after t change nothing up to t; a cut video is padded
        spliced = torch.cat([frames[:, : t + 1], other[:, t + 1 :]], dim=1)
        assert torch.allclose(scorer.surprise(spliced)[:, : t + 1], surprise[:, : t + 1])
        assert torch.allclose(scorer.surprise(frames[:, : t + 1]), surprise[:, : t + 1])
    assert scorer.expected_frames(frames).shape == (2, 6, 3, 32, 32)
    with pytest.raises(
        ValueError,
        match=r"videos of 8 frames are longer than this VideoMAE's "
        r"num_frames 6",
    ):
        scorer.surprise(video(frames=8))


def test_a_saved_model_loads_from_its_local_folder(tmp_path):
    torch.manual_seed(0)
    built = VideoMAEScorer(config=CONFIG)
    built.model.save_pretrained(tmp_path / "videomae")
    loaded = VideoMAEScorer(pretrained=str(tmp_path / "videomae"))
    assert torch.equal(loaded.surprise(video()), built.surprise(video()))
    with pytest.raises(ValueError, match=r"either pretrained \(a local folder\) or config"):
        VideoMAEScorer()


def test_test_on_our_probes_runs_without_a_checkpoint(tmp_path, monkeypatch):
    torch.manual_seed(0)
    tiny = {**CONFIG, "num_frames": 8}  # the tiny config's videos
    VideoMAEScorer(config=tiny).model.save_pretrained(tmp_path / "videomae")
    monkeypatch.chdir(tmp_path)
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--model",
            "voe_lightning.model.VideoMAEScorer",
            "--model.init_args.pretrained",
            str(tmp_path / "videomae"),
            "--trainer.enable_progress_bar",
            "false",
        ]
    )
    assert (tmp_path / "runs" / "tiny" / "version_0" / "voe_report" / "summary.json").is_file()

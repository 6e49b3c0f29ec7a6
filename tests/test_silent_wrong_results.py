"""Issue 59: nothing silently wrong, round five. Seven inputs that gave a wrong result, or
none, without saying so; docs/reliability.md lists each case with its test."""

import contextlib
import json
import math
import os
import threading
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from helpers import ALPHA, refused
from helpers.intphys import SCENES, datamodule, make_intphys
from helpers.locations import TINY_CONFIG
from PIL import Image

from voe_lightning.benchmarks.intphys2.reader import Video, VideoDataset
from voe_lightning.benchmarks.metrics import write_answer_file
from voe_lightning.callbacks import IntPhys2LeaderboardWriter, VOEProbeCallback
from voe_lightning.cli import main
from voe_lightning.model import CallableModel
from voe_lightning.stats.statistics import paired_test
from voe_lightning.stats.streaming_statistics import PairedSurpriseStats

CALLABLE = ["--model", "voe_lightning.model.CallableModel", "--model.init_args.function"]


def zeros(frames: torch.Tensor) -> torch.Tensor:
    """A constant scorer: no surprise anywhere."""
    return torch.zeros(frames.shape[:2])


def brightness(frames: torch.Tensor) -> torch.Tensor:
    """A float64 motion-blind scorer: a frame's mean brightness."""
    return frames.double().mean(dim=(2, 3, 4))


def brightness_plus_1e9(frames: torch.Tensor) -> torch.Tensor:
    """The same plus 1e9, which cancels in every d."""
    return brightness(frames) + 1e9


def brightness_plus_1e9_as_list(frames: torch.Tensor) -> list:
    """The same as Python floats (float64 values without a dtype)."""
    return brightness_plus_1e9(frames).tolist()


def bright_pixels_plus_2_40(frames: torch.Tensor) -> torch.Tensor:
    """An int64 count beyond float32's integers (2^24)."""
    return (frames > 127).sum(dim=(2, 3, 4)) + 2**40


def half_brightness(frames: torch.Tensor) -> torch.Tensor:
    return brightness(frames).half()


# ------------------------------------------------------------------- 1: a figure not drawn
def test_a_model_without_surprise_gets_its_report_without_the_tsne_figure(workdir):
    with pytest.warns(UserWarning, match="differ by at most 0 over every frame") as warned:
        main(["test", "--config", TINY_CONFIG, *CALLABLE, "test_silent_wrong_results.zeros"])
    assert any(str(w.message).endswith("tsne_object_persistence.png not written") for w in warned)
    [report] = workdir.rglob("voe_report")
    summary = json.loads((report / "summary.json").read_text())
    assert [row["n"] for row in summary["rows"]] == [3, 3, 6, 3]  # the statistics, all there
    assert not (report / "tsne_object_persistence.png").exists()
    assert (report / "histograms.png").exists() and (report / "pairs.csv").exists()


# ------------------------------------------------------------- 2: a callable's float64 surprise
def test_a_callables_float64_or_integer_surprise_is_kept_in_float64():
    frames = torch.randint(0, 256, (2, 4, 8, 8, 3), dtype=torch.uint8)

    def d(function):  # S(second video) - S(first), as the report computes it (in float64)
        surprise = CallableModel(f"test_silent_wrong_results.{function}").surprise(frames)
        return surprise, (surprise[1].double().sum() - surprise[0].double().sum()).item()

    plain, plain_d = d("brightness")
    assert plain.dtype == torch.float64 and plain_d != 0.0
    for function in ("brightness_plus_1e9", "brightness_plus_1e9_as_list"):
        offset, offset_d = d(function)
        assert offset.dtype == torch.float64, function
        assert offset_d == pytest.approx(plain_d, rel=1e-6), function  # float32: 0 or +-64
    counts, _ = d("bright_pixels_plus_2_40")
    assert counts.dtype == torch.float64
    assert torch.equal(counts - 2**40, (frames > 127).sum(dim=(2, 3, 4)).double())
    assert d("half_brightness")[0].dtype == torch.float16  # a floating dtype as given


# ------------------------------------------------------------ 3: an overflowed streaming variance
def test_the_streaming_test_refuses_moments_beyond_float64_as_the_one_shot_does():
    inconsistent, consistent = [2e200, -1e200], [0.0, 0.0]  # scipy: t = 0, p = .5
    with pytest.raises(ValueError, match="moments of the differences are not finite"):
        paired_test(inconsistent, consistent, bootstrap=0, alpha=ALPHA)
    metric = PairedSurpriseStats()
    metric.update(torch.tensor(inconsistent, dtype=torch.float64), torch.tensor(consistent))
    with pytest.raises(
        ValueError,
        match=r"moments of the differences are not finite: over n=2 pairs, sum d = 1e\+200, "
        r"sum d\^2 = inf; ",
    ):
        metric.compute()  # was t = +inf, p = 0: the zero-variance rule on max(0, inf - inf)
    one_pair = PairedSurpriseStats()
    one_pair.update(torch.tensor([1.0]), torch.tensor([0.0]))
    callback = VOEProbeCallback(print_table=False, alpha=ALPHA)
    callback.metrics = {("voe", "object_persistence", "counterbalanced"): one_pair}
    assert callback._results("voe") == {}  # too few pairs so far: passed over
    callback.metrics[("voe", "object_persistence", "standard")] = metric
    with pytest.raises(ValueError, match="moments of the differences are not finite"):
        callback._results("voe")  # refused, not passed over as too few pairs


# ------------------------------------------------------------ 4, 5: the IntPhys 2 leaderboard
def _leaderboard(tmp_path, names, surprise_max):
    """The jsonl IntPhys2LeaderboardWriter writes of HeldOut videos ``names`` (metadata.csv
    lines 2, 3, ...) scored ``surprise_max``, threshold 1."""
    videos = [Video(tmp_path / f"{i}.mp4", name, i + 2) for i, name in enumerate(names)]
    dataset = VideoDataset(videos, sampling=None)
    trainer = SimpleNamespace(
        world_size=1, is_global_zero=True, predict_dataloaders=SimpleNamespace(dataset=dataset)
    )
    writer = IntPhys2LeaderboardWriter(threshold=1.0, path=tmp_path / "heldout.jsonl")
    batch = {"index": torch.arange(len(names)), "surprise_max": torch.tensor(surprise_max)}
    writer.write_on_epoch_end(trainer, None, [batch], [])
    return [json.loads(line) for line in writer.path.read_text().splitlines()]


def test_the_leaderboard_refuses_two_videos_of_one_name_listing_both(tmp_path):
    assert [
        line["model_answer"] for line in _leaderboard(tmp_path, "abcd", [0.5, 2.0, 1.0, 3.0])
    ] == [
        1,
        0,
        1,
        0,
    ]
    (tmp_path / "heldout.jsonl").unlink()
    with pytest.raises(ValueError, match="names 2 videos 'b'") as refused:
        _leaderboard(tmp_path, ["a", "b", "c", "b"], [0.5, 2.0, 1.0, 3.0])  # was 3 lines
    assert f"{tmp_path / '1.mp4'} (metadata.csv line 3)" in str(refused.value)
    assert f"{tmp_path / '3.mp4'} (metadata.csv line 5)" in str(refused.value)
    assert not (tmp_path / "heldout.jsonl").exists()


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_the_leaderboard_refuses_non_finite_surprise_as_answer_txt_does(tmp_path, bad):
    with pytest.raises(ValueError, match="surprise must be finite"):
        write_answer_file(tmp_path / "answer.txt", {f"O1/0001/{m}": bad for m in range(1, 5)})
    with pytest.raises(
        ValueError, match=f"1 of 4 videos have a non-finite surprise_max \\('b': {bad}\\)"
    ):
        _leaderboard(tmp_path, "abcd", [0.5, bad, 1.0, 3.0])  # NaN was model_answer 0
    assert not (tmp_path / "heldout.jsonl").exists()


# ------------------------------------------------------------------ 6: the IntPhys decoded cache
def test_the_intphys_cache_sees_frames_rewritten_in_place(tmp_path):
    root = make_intphys(tmp_path / "intphys")
    scene, (_, _, folders) = next(iter(SCENES.items()))
    cache = str(tmp_path / "cache")

    def probes(**options):
        return torch.cat(list(datamodule(root, **options).test_dataloader()))

    before = probes(cache_dir=cache)
    for number in (11, 15):  # two sampled frames of the impossible movie, in place
        path = root / "dev" / scene / folders[2] / "scene" / f"scene_{number:03d}.png"
        image = np.asarray(Image.open(path)).copy()
        image[:6, :6] = 255
        Image.fromarray(image).save(path)
    uncached = probes(cache_dir=None)
    assert not (uncached["inconsistent", "frames"] == before["inconsistent", "frames"]).all()
    cached = probes(cache_dir=cache)  # was the stale frames: scene/'s size and mtime held
    assert (cached == uncached).all()


# ------------------------------------------------------------- 7: --config read before parsing
@contextlib.contextmanager
def _unblocked(fifo):
    """Opens ``fifo``'s write end over and over while the block runs, so code that opens it to
    read gets an empty file instead of hanging the test."""
    stop = threading.Event()

    def open_and_close():
        while not stop.wait(0.2):
            with contextlib.suppress(OSError):  # no reader yet
                os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))

    thread = threading.Thread(target=open_and_close, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


@pytest.mark.parametrize("given", ["--config config.yaml", "-c config.yaml", "--conf=config.yaml"])
def test_a_config_that_is_a_pipe_or_device_is_refused_before_it_is_opened(workdir, capsys, given):
    os.mkfifo(workdir / "config.yaml")
    with _unblocked(workdir / "config.yaml"):  # was a hang
        line = refused(capsys, ["fit", *given.split()])
    assert line == (
        "error: --config config.yaml is a pipe (FIFO), not a regular file: give a YAML file "
        "(a pipe, device or /dev/stdin would be read whole before the parser reads it again)"
    )
    line = refused(capsys, ["fit", "--config", "/dev/zero"])  # was 24 GB read, then killed
    assert line.startswith("error: --config /dev/zero is a character device, not a regular file")


def test_a_config_larger_than_any_config_is_refused_unread(workdir, capsys):
    big = workdir / "big.yaml"
    big.write_text("# " + "x" * (1 << 20) + "\n")
    line = refused(capsys, ["fit", "--config", "big.yaml"])
    assert line == (
        "error: --config big.yaml is 1,048,579 bytes, more than the 1,048,576 a config may "
        "be (the package's own are under 5 KB): give a YAML config file"
    )

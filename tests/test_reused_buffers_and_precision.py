"""Nothing silently wrong with a model's surprise as it arrives: a model that reuses its output
buffer, one that reads a frame ahead where a pair's frames stay identical past the manipulation
frame, surprise in bf16, sums that overflow and a causality check that compared nothing
(issue 73; docs/reliability.md lists each case with its test)."""

import json

import numpy as np
import pytest
import torch
from helpers import error_line
from helpers.locations import TINY_CONFIG
from tensordict import TensorDict

from voe_lightning.cli import NOT_CAUSAL_EXIT, main
from voe_lightning.model.base import inputs_first_difference
from voe_lightning.stats.causality import check_prefix
from voe_lightning.stats.surprise_window import first_difference, video_surprise

MODELS = "helpers.reused_buffer_models"
CALLABLE = ["--model", "voe_lightning.model.CallableModel", "--model.init_args.function"]


def _test(*arguments: str) -> None:
    main(["test", "--config", TINY_CONFIG, *arguments])


def _pairs_csv(workdir, version: int) -> str:
    return (
        workdir / "runs" / "tiny" / f"version_{version}" / "voe_report" / "pairs.csv"
    ).read_text()


# ----------------------------------------------------------------------------- reused buffers
def test_a_model_reusing_its_output_buffer_gets_each_batchs_own_surprise(workdir):
    """Six pairs in batches of four and two: each batch's surprise is kept as it arrived, so
    pairs.csv is the fresh-array version's, byte for byte (and the causal model passes)."""
    _test(*CALLABLE, f"{MODELS}.frame_change")
    _test(*CALLABLE, f"{MODELS}.frame_change_into_buffer")
    fresh, reused = _pairs_csv(workdir, 0), _pairs_csv(workdir, 1)
    assert len(fresh.splitlines()) == 7  # a header and 6 pairs
    assert reused == fresh


def test_check_causality_of_a_future_reader_reusing_its_buffer_calls_it_not_causal(capsys):
    """The whole video's surprise is kept as it arrived, not overwritten by each cut's."""
    with pytest.raises(SystemExit) as raised:
        main(
            [
                "check-causality",
                "--concepts",
                "[object_persistence]",
                "--seeds",
                "1",
                "--num_frames",
                "6",
                *CALLABLE,
                f"{MODELS}.next_brightness_into_buffer",
            ]
        )
    assert raised.value.code == 2
    printed = capsys.readouterr()
    assert "object_persistence, videos cut after each frame t: NOT causal" in printed.out
    assert "object_persistence (videos cut after each frame t)" in printed.err


# ----------------------------------------------------------------------------- causality gap
def test_the_prefix_check_compares_every_frame_before_the_first_difference():
    """Frames 3 and 4 are identical although the manipulation frame is 2: compared too."""
    consistent = torch.zeros(2, 6)
    inconsistent = consistent.clone()
    inconsistent[0, 3] = 1.0  # before the first difference (5): reads the future
    inconsistent[1, 5] = 1.0  # at the first difference: allowed
    found = check_prefix(consistent, inconsistent, torch.tensor([2, 2]), torch.tensor([5, 5]))
    assert (found.pairs, found.non_causal, found.first_frame) == (2, 1, 3)
    assert "(before their first difference) in 1 of 2 pairs" in found.line()


@pytest.mark.slow
def test_a_model_reading_one_frame_ahead_on_unchangeableness_gets_no_verdict(workdir, capsys):
    """At 15 frames every unchangeableness pair's frames stay identical at least one frame past
    its manipulation frame, so a model reading frame t + 1 differs only there."""
    with pytest.raises(SystemExit) as raised:
        _test(
            *CALLABLE,
            f"{MODELS}.next_brightness",
            "--data.init_args.concept",
            "unchangeableness",
            "--data.init_args.num_frames",
            "15",
        )
    assert raised.value.code == NOT_CAUSAL_EXIT
    assert "test: causality: the model is not causal" in error_line(capsys)
    [report] = workdir.rglob("voe_report")
    summary = json.loads((report / "summary.json").read_text())
    assert summary["causality"]["non_causal_pairs"] == summary["causality"]["pairs"] == 18
    pairs = np.genfromtxt(report / "pairs.csv", delimiter=",", names=True, dtype=None)
    assert (pairs["first_difference"] >= pairs["manipulation_frame"] + 2).all()  # the gap
    assert {v["verdict"] for v in summary["verdicts"]} == {
        "no verdict: the model reads frames after t"
    }


def test_a_causality_check_that_compared_no_frame_says_so():
    """Pairs whose videos differ from their first frame leave nothing to compare: not a pass."""
    found = check_prefix(torch.zeros(2, 4), torch.ones(2, 4), torch.tensor([1, 1]), [0, 0])
    assert found.causal and not found.checked
    assert found.line() == (
        "causality: not checked: no frame compared: the two videos of each of the 2 pairs "
        "differ from their first frame"
    )
    assert found.counted("pairs").startswith("NOT checked")
    assert found.merge(check_prefix(torch.zeros(1, 4), torch.zeros(1, 4), [1])).line() == (
        "causality: per-frame surprise identical before each pair's first difference (where "
        "the two videos' inputs are) in all 1 pairs compared (2 pairs differ from their first frame: not "
        "compared)"
    )


# ----------------------------------------------------------------------------- precision
def test_validation_of_bf16_surprise_sums_it_as_float32_would(workdir):
    """A frame-local scorer in bf16 gets the statistics of the same values in float32: each
    quadruplet's D = 0 exactly, no t from rounding."""
    runs = [
        main(["validate", "--config", TINY_CONFIG, *CALLABLE, f"{MODELS}.{name}"])
        for name in ("brightness_bf16", "brightness_bf16_as_float32")
    ]
    bf16, float32 = (
        {k: float(v) for k, v in run.trainer.callback_metrics.items() if k.startswith("voe/")}
        for run in runs
    )
    assert bf16.keys() == float32.keys()
    np.testing.assert_array_equal(list(bf16.values()), list(float32.values()))  # NaN = NaN
    assert bf16["voe/object_persistence/quadruplet/relative_surprise"] == 0.0
    halves = [bf16[f"voe/object_persistence/quadruplet/{h}_half"] for h in ("first", "second")]
    assert halves[0] == -halves[1] != 0.0


def test_test_of_bf16_surprise_writes_the_float32_pairs(workdir):
    _test(*CALLABLE, f"{MODELS}.brightness_bf16")
    _test(*CALLABLE, f"{MODELS}.brightness_bf16_as_float32")
    assert _pairs_csv(workdir, 0) == _pairs_csv(workdir, 1)


def test_a_sum_of_finite_surprise_is_made_in_float64_and_an_overflow_named():
    """float32 surprise of 3e38 a frame sums to 1.8e39, not inf; a float64 sum that overflows
    is named as the sum's overflow, not as the model's infinite surprise."""
    per_frame = torch.full((2, 6), 3e38, dtype=torch.float32)
    assert video_surprise(per_frame).tolist() == pytest.approx([6 * 3e38] * 2, rel=1e-6)
    with pytest.raises(ValueError, match=r"overflows float64: every per-frame value is finite"):
        video_surprise(np.full((2, 3), 1e308))
    assert np.isinf(video_surprise(np.array([[1.0, np.inf]])))[0]  # the model's own inf


def test_the_prefix_check_ends_where_any_input_differs_before_the_frames():
    """An object state can differ a frame before the pixels show it (containment's container,
    1e-5 m apart while the frames are identical): a model reading states is causal there."""
    frames = torch.zeros(2, 6, 2, 2, 3, dtype=torch.uint8)
    later = frames.clone()
    later[:, 4:] = 1  # the frames differ from frame 4
    states = TensorDict({"position": torch.zeros(2, 6, 3, 3)}, batch_size=[2, 6, 3])
    moved = states.clone()
    moved["position"][0, 2:] += 1e-5  # the first pair's states differ from frame 2
    first = first_difference(frames, later)
    earliest = inputs_first_difference({"objects": states}, {"objects": moved}, first)
    assert first.tolist() == [4, 4] and earliest.tolist() == [2, 4]
    follows_states = torch.zeros(2, 6)
    follows_states[0, 2:] = 1.0  # reads the states as they arrive
    assert check_prefix(follows_states, torch.zeros(2, 6), [1, 1], earliest).causal
    assert not check_prefix(follows_states, torch.zeros(2, 6), [1, 1], first).causal

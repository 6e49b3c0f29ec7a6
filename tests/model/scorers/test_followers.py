"""ObjectFollower: rules with no dynamics over per-object inputs, checked against hand
computations on one hand-made video of states and one of masks, refusing what they cannot read,
and run by ``test`` with no checkpoint."""

import csv
import json

import pytest
import torch
from helpers.locations import TINY_CONFIG
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.cli import main
from voe_lightning.model import ObjectFollower
from voe_lightning.model.scorers.followers import RULES

T, K = 5, specs.OBJECT_SLOTS


def _states() -> TensorDict:
    """One video: id 1 seen at frames 0, 1 and 3 (hidden at 2, gone at 4), moving 0.1 m a frame
    along x and changing colour at frame 3; id 2 never seen."""
    position = torch.zeros(1, T, K, 3)
    position[0, :, 1, 0] = torch.arange(T) * 0.1
    color = torch.full((1, T, K, 3), 0.5)
    color[0, 3:, 1] = torch.tensor([1.0, 0.5, 0.5])
    visible = torch.zeros(1, T, K)
    visible[0, [0, 1, 3], 1] = 0.2
    shape = torch.zeros(1, T, K, dtype=torch.int64)
    shape[0, :, 1] = 1
    return TensorDict(
        {
            "position": position,
            "orientation": torch.zeros(1, T, K, 4),
            "size": torch.full((1, T, K, 3), 0.1),
            "shape_label": shape,
            "color": color,
            "visible_fraction": visible,
        },
        batch_size=[1, T, K],
    )


FRAMES = torch.zeros(1, T, 4, 4, 3, dtype=torch.uint8)

# Frame by frame, by hand: stay_put reads id 1 at 1 (0.1 from frame 0) and 3 (0.2 from frame 1);
# attributes at 3 (red 0.5 -> 1.0); seen_again at 2 and 4; copy_last at 1 only (0.1 m squared).
EXPECTED = {
    "stay_put": [0, 0.1, 0, 0.2, 0],
    "attributes": [0, 0, 0, 0.5, 0],
    "seen_again": [0, 0, 1, 0, 1],
    "same_and_seen": [0, 0, 1, 1, 1],
    "nothing_changes": [0, 1, 1, 2, 1],
    "copy_last": [0, 0.01, 0, 0, 0],
    "linear_extrapolation": [0, 0, 0, 0, 0],
}


@pytest.mark.parametrize("rule", list(EXPECTED))
def test_each_state_rule_scores_the_hand_made_video_as_computed_by_hand(rule):
    model = ObjectFollower(rule, "states")
    assert list(model.parameters()) == []
    surprise = model.surprise(FRAMES, objects=_states())
    assert surprise.shape == (1, T)
    assert torch.allclose(
        surprise[0], torch.tensor(EXPECTED[rule], dtype=torch.float32), atol=1e-6
    ), surprise


def test_mask_rules_read_centroid_area_and_colour_of_what_is_seen():
    """A 2-pixel object of id 3 moves one pixel right at frame 1, turns red at frame 2 and is
    hidden at frame 3; stay_put is the image-plane move (a pixel is 2 / height = 0.5 units)."""
    mask = torch.zeros(1, 4, 4, 4, dtype=torch.uint8)
    frames = torch.zeros(1, 4, 4, 4, 3, dtype=torch.uint8)
    mask[0, 0, 0, 0:2] = 3
    mask[0, 1:3, 0, 1:3] = 3
    frames[0, 2, 0, 1:3, 0] = 255
    moved = ObjectFollower("stay_put", "masks").surprise(frames, mask)
    assert torch.allclose(moved[0], torch.tensor([0.0, 0.5, 0.0, 0.0]))
    changed = ObjectFollower("attributes", "masks").surprise(frames, mask)
    assert changed[0, 2] == pytest.approx(1.0) and changed[0, 1] == 0
    gone = ObjectFollower("seen_again", "masks").surprise(frames, mask)
    assert gone[0].tolist() == [0, 0, 0, 1]


def test_an_unknown_rule_or_input_and_missing_states_are_refused():
    with pytest.raises(ValueError, match="unknown rule 'fly'; valid rules are: stay_put"):
        ObjectFollower("fly")
    with pytest.raises(ValueError, match="unknown features 'depth'"):
        ObjectFollower("stay_put", "depth")
    with pytest.raises(ValueError, match="has none: use features 'masks'"):
        ObjectFollower("stay_put", "states").surprise(FRAMES)
    mask = torch.zeros(1, T, 4, 4, dtype=torch.uint8)
    with pytest.raises(ValueError, match="'rgbd' reads the records' depth .* use features 'masks'"):
        ObjectFollower("stay_put", "rgbd").surprise(FRAMES[:, :, :4, :4], mask)


def test_rgbd_rules_read_the_depth_beside_the_masks():
    """The mask video above, its object 2 m away, then 2.5 m at frame 1, its outline cut
    (a share of 0.5) from frame 2: the mean depth joins the position and, times the pixels'
    half-extents, the largest size shown (0.5 by 0.25 of the image plane at 2 m, then 2.5 m:
    (1.0, 0.5), then (1.25, 0.625)) joins the attributes; the cut share, which the RGB-D rung
    does not read, changes none."""
    mask = torch.zeros(1, 4, 4, 4, dtype=torch.uint8)
    frames = torch.zeros(1, 4, 4, 4, 3, dtype=torch.uint8)
    mask[0, :3, 0, 0:2] = 3
    depth = torch.zeros(1, 4, specs.OBJECT_SLOTS, 3)
    depth[0, :3, 3] = torch.tensor([[2.0, 2.0, 0.0], [2.5, 2.5, 0.0], [2.5, 2.5, 0.5]])
    follower = ObjectFollower("stay_put", "rgbd")
    assert follower.inputs_read() == frozenset({"mask", "depth"})
    moved = follower.surprise(frames, mask, depth=depth)
    assert torch.allclose(moved[0], torch.tensor([0.0, 0.5, 0.0, 0.0]))
    changed = ObjectFollower("attributes", "rgbd").surprise(frames, mask, depth=depth)
    assert torch.allclose(changed[0], torch.tensor([0.0, (0.25**2 + 0.125**2) ** 0.5, 0.0, 0.0]))
    assert ObjectFollower("seen_again", "rgbd").surprise(frames, mask, depth=depth)[0, 3] == 1


def test_test_scores_a_follower_with_no_checkpoint(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    main(
        [
            "test",
            "--config",
            str(TINY_CONFIG),
            "--model",
            "voe_lightning.model.ObjectFollower",
            "--model.init_args.rule",
            "stay_put",
            "--model.init_args.features",
            "rgbd",
            "--trainer.logger.init_args.name",
            "follower",
            "--trainer.enable_progress_bar",
            "false",
        ]
    )
    (summary,) = tmp_path.glob("runs/follower/*/voe_report/summary.json")
    assert json.loads(summary.read_text())["source"]["checkpoint"] is None
    # Its report's cue audit holds the followers of what it reads (the masks and their depth,
    # handed to it with its expected frames), not the states'.
    report = summary.parent
    rows = list(csv.DictReader((report / "cues.csv").open()))
    cues = {row["cue"] for row in rows}
    assert {f"{features}_{rule}" for rule in RULES for features in ("masks", "rgbd")} <= cues
    assert not any(cue.startswith("states_") for cue in cues)
    assert "Followers of the model's own inputs" in (report / "cues.md").read_text()
    # the summary says under the verdicts which concepts a follower passes too, and the
    # stay-put follower's rows there are its own rows: the same rule on the same pairs
    document = json.loads(summary.read_text())
    assert isinstance(document["followers_passing"], dict)
    assert "Followers of the model's own inputs (cues.md): " in (report / "summary.md").read_text()
    own = {(r["concept"], r["variant"]): r for r in csv.DictReader((report / "summary.csv").open())}
    followed = [r for r in rows if r["cue"] == "rgbd_stay_put" and r["t"]]
    assert followed
    for row in followed:
        model_row = own[(row["concept"], row["variant"])]
        assert float(row["t"]) == pytest.approx(float(model_row["t"]), rel=1e-6, nan_ok=True)

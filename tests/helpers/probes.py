"""The checks every probe pair passes (docs/architecture.md §4), shared by the scene validity
test and the harness-length presets' test."""

import torch


def check_probe_pair(record, concept: str, variant: str, where: str) -> None:
    """One pair: identical through the manipulation frame (frames, masks, depth, object states), the
    manipulated ids unseen there (solidity: no more of the block shows where it sinks than
    where it rests), and the two videos differ after it; ``where`` names it in a failure."""
    m = int(record["manipulation_frame"])
    consistent, inconsistent = record["consistent"], record["inconsistent"]
    states = [("objects", name) for name in consistent["objects"].keys()]
    for key in ("frames", "mask", "depth", *states):
        assert torch.equal(consistent[key][: m + 1], inconsistent[key][: m + 1]), (
            f"{where}: {key} differ up to manipulation frame {m}"
        )
    ids = [i for i in record["manipulated_ids"].tolist() if i]
    assert ids, f"{where}: a probe must name the manipulated object ids"
    if concept == "solidity":
        # The penetration is hidden behind the container's front face: whatever of the block
        # shows in the video where it sinks (standard: inconsistent) also shows in the one
        # where it rests (the counterbalanced pair is the mirror).
        sinks, rests = (
            (inconsistent, consistent) if variant == "standard" else (consistent, inconsistent)
        )
        for t in range(m, consistent["mask"].shape[0]):
            for i in ids:
                extra = (sinks["mask"][t] == i) & (rests["mask"][t] != i)
                assert extra.sum() <= 2, f"{where}: penetration visible at frame {t}"
    else:
        for video in (consistent, inconsistent):
            visible = set(video["mask"][m].unique().tolist())
            assert not visible & set(ids), (
                f"{where}: manipulated ids {ids} visible at manipulation frame {m}"
            )
    assert not torch.equal(consistent["frames"][m:], inconsistent["frames"][m:]), (
        f"{where}: the two videos never differ"
    )

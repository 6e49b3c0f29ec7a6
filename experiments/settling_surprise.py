"""What a propped plank's settling costs the positive control: in object persistence's test
probes, the video in which the plank ends propped on the object (standard: consistent;
counterbalanced: inconsistent), at the frames after it lands (the first frame that takes it
down by less than 0.2 m, ``cue_through_violation.landing_frame``), split into frames in which
it still settles (moves more than 1 cm or turns more than 0.01 rad) and frames in which it lies
still: how many, the control's state surprise of the plank there, its mixture weights (as the
dynamics give them) and each Gaussian's negative log-likelihood of each part of the seen state
(what hard assignment chose by), per checkpoint.

    python experiments/settling_surprise.py runs/r16_s0/version_0/checkpoints/last.ckpt \
        --root data/cpu
"""

import argparse
from unittest import mock

import numpy as np
import torch
from cue_through_violation import landing_frame
from free_fall import PARTS, part_nats

from voe_lightning import specs
from voe_lightning.data.store import open_split
from voe_lightning.model import ObjectStateModel, likelihood
from voe_lightning.model.likelihood import rectified_excess
from voe_lightning.model.object_state import rollout
from voe_lightning.model.object_state.state import STATE_SIZE

#: After landing, a frame in which the plank moves or turns by more than these still settles.
MOVES, TURNS = 0.01, 0.01


def propped_videos(root: str, pairs: int) -> tuple:
    """The first ``pairs`` test pairs of each variant: the propped video's frames, objects and
    camera stacked, each video's manipulation frame and its variant."""
    chosen, count = [], dict.fromkeys(specs.STANDARD_VARIANTS["object_persistence"], 0)
    for record in open_split(root, "object_persistence", "test"):
        variant = specs.VARIANTS[int(record["variant"])]
        if count.get(variant, pairs) < pairs:
            count[variant] += 1
            side = "consistent" if variant == "standard" else "inconsistent"
            chosen.append((record[side], record["camera"], record["manipulation_frame"], variant))
    videos, cameras, frames, variants = zip(*chosen)
    return torch.stack(videos), torch.stack(cameras), torch.stack(frames), variants


def settling_rows(
    model: ObjectStateModel, videos, cameras, manipulation, variants
) -> dict[tuple[str, str], np.ndarray]:
    """Per frame after landing, by variant and kind ("settling", "still"): the plank's state
    surprise, the mixture weights the dynamics gave it for that frame and each Gaussian's
    negative log-likelihood of each part of the state (``PARTS``) [N, 1 + K + 4 K]."""
    caught, scored = [], []
    nll = likelihood.mixture_nll

    def spy(observed, means, log_std, logits, hard=False):
        scored.append(part_nats(observed, means, log_std))  # [B, S, parts, K]
        return nll(observed, means, log_std, logits, hard=hard)

    hook = model.dynamics.register_forward_hook(lambda _, __, out: caught.append(out))
    observations = model._inputs(videos["frames"], videos["objects"], cameras)
    with torch.no_grad(), mock.patch.object(rollout, "mixture_nll", spy):
        out = model.rollout(observations)
    hook.remove()
    components = model.hparams.components
    start = components * 2 * STATE_SIZE
    weights = torch.stack([o[..., start : start + components] for o in caught], 1).softmax(-1)
    surprise = rectified_excess(out["state"], out["state_entropy"])
    state, seen = observations.state, observations.visible
    rows: dict[tuple[str, str], list] = {}
    for b in range(state.shape[0]):
        plank = int(state[b, 0, :, 7:10].amax(-1).argmax())  # the longest box
        position, orientation = state[b, :, plank, :3], state[b, :, plank, 3:7]
        landed = landing_frame(position[:, 2], int(manipulation[b]))
        if landed is None:
            continue
        for t in range(landed + 1, state.shape[1]):
            if not (seen[b, t, plank] and seen[b, t - 1, plank]):
                continue
            moved = float((position[t] - position[t - 1]).norm())
            cosine = float((orientation[t] * orientation[t - 1]).sum().abs().clamp(max=1.0))
            kind = "settling" if moved > MOVES or 2 * np.arccos(cosine) > TURNS else "still"
            rows.setdefault((variants[b], kind), []).append(
                [
                    float(surprise[b, t, plank]),
                    *weights[b, t - 1, plank].tolist(),
                    *scored[t - 1][b, plank].flatten().tolist(),
                ]
            )
    return {key: np.array(values) for key, values in sorted(rows.items())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument("--pairs", type=int, default=100, help="test pairs per variant")
    args = parser.parse_args()
    torch.set_num_threads(1)
    videos, cameras, manipulation, variants = propped_videos(args.root, args.pairs)
    for checkpoint in args.checkpoints:
        model = ObjectStateModel.load_from_checkpoint(checkpoint, map_location="cpu").eval()
        print(checkpoint)
        k = model.hparams.components
        for (variant, kind), rows in settling_rows(
            model, videos, cameras, manipulation, variants
        ).items():
            print(
                f"  {variant:15s} {kind:8s} {len(rows):4d} frames: state surprise {rows[:, 0].mean():6.2f} "
                f"nats a frame (median {np.median(rows[:, 0]):.2f}); weights (stop, move..., "
                f"land) {np.round(rows[:, 1 : 1 + k].mean(0), 2).tolist()}"
            )
            for name, cost in zip(PARTS, rows[:, 1 + k :].mean(0).reshape(len(PARTS), k)):
                print(f"      {name:12s} nats per Gaussian {np.round(cost, 1).tolist()}")


if __name__ == "__main__":
    main()

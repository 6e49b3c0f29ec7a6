"""Where the positive control expects a falling plank to land: for object persistence's
training clips (examples and planks dropped on an empty floor) and its validation probes, the
plank's height one frame before it comes to rest, at rest, and as predicted for that frame
(the most probable component), in metres, means over the videos. Beside them, two
extrapolations of the two frames before, each raised to rest on the floor: the last move
repeated with the orientation kept (the control's inertia), and with the last turn repeated too.

    python experiments/plank_landing.py runs/r7_s0/version_0/checkpoints/last.ckpt \
        --root data/cpu
"""

import argparse

import mujoco
import numpy as np
import torch

from voe_lightning import specs
from voe_lightning.data.store import open_split
from voe_lightning.datamodules import VOEDataModule
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.base import video_inputs
from voe_lightning.model.object_state.geometry import on_or_above_floor

#: A plank is at rest from the first frame within this distance (m) of its final height.
AT_REST = 0.03


def extrapolated(before: torch.Tensor, last: torch.Tensor, turn: bool) -> float:
    """The height of an object whose states two frames and one frame back are ``before`` and
    ``last`` [13], after its last move (and, with ``turn``, its last turn) repeated, on or above
    the floor."""
    state = last.clone()
    state[:3] = 2 * last[:3] - before[:3]
    if turn:  # MuJoCo's (w, x, y, z) quaternions: the last turn, then repeated
        previous, latest = before[3:7].double().numpy(), last[3:7].double().numpy()
        inverse, change, turned = np.empty(4), np.empty(4), np.empty(4)
        mujoco.mju_negQuat(inverse, previous)
        mujoco.mju_mulQuat(change, latest, inverse)
        mujoco.mju_mulQuat(turned, change * (1.0 if change[0] >= 0 else -1.0), latest)
        state[3:7] = torch.from_numpy(turned).to(state)
    return float(on_or_above_floor(state)[2])


def landings(model: ObjectStateModel, frames, objects, camera) -> np.ndarray:
    """Per video whose plank (the object with the largest extent) lands in view: its height
    the frame before it comes to rest, at rest, as predicted for that frame, and as the two
    extrapolations [N, 5]."""
    observations = model._inputs(frames, objects, camera)
    with torch.no_grad():
        predicted = model.rollout(observations)["predicted"][..., 2]
    height = observations.state[..., 2]
    plank = observations.state[..., 7:10].amax(1).amax(-1).argmax(-1)
    rows = []
    for video, slot in enumerate(plank.tolist()):
        z = height[video, :, slot]
        landed = int(torch.nonzero((z - z[-1]).abs() < AT_REST)[0])
        if landed >= 2 and observations.visible[video, landed - 2 : landed + 1, slot].all():
            before, last = observations.state[video, landed - 2 : landed, slot]
            rows.append(
                (
                    float(z[landed - 1]),
                    float(z[landed]),
                    float(predicted[video, landed, slot]),
                    extrapolated(before, last, turn=False),
                    extrapolated(before, last, turn=True),
                )
            )
    return np.array(rows).reshape(-1, 5)


def report(name: str, rows: np.ndarray) -> None:
    before, rest, predicted, moved, turned = rows.mean(0)
    print(
        f"{name:38s} {len(rows):3d} landings | before {before:.2f} m, at rest {rest:.2f} m, "
        f"predicted {predicted:.2f} m | move repeated {moved:.2f} m, "
        f"move and turn {turned:.2f} m"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument("--clips", type=int, default=400, help="training clips read")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = ObjectStateModel.load_from_checkpoint(args.checkpoint, map_location="cpu").eval()
    clips = open_split(args.root, "object_persistence", "train")
    records = [clips[index] for index in range(min(args.clips, len(clips)))]
    for name in specs.CLIP_KINDS_BY_CONCEPT["object_persistence"]:
        kind = specs.CLIP_KINDS.index(name)
        chosen = [record for record in records if int(record["kind"]) == kind]
        if chosen:
            batch = torch.stack(chosen)
            rows = landings(model, batch["frames"], batch["objects"], batch["camera"])
            for ending, chosen_rows in (
                ("flat", rows[rows[:, 1] < 0.15]),
                ("propped", rows[rows[:, 1] >= 0.15]),
            ):
                if len(chosen_rows):
                    report(f"training {name}, {ending}", chosen_rows)
    data = VOEDataModule(
        concepts=["object_persistence"],
        root=args.root,
        train_examples=2000,
        val_pairs=24,
        test_pairs=200,
        generalization_pairs=100,
        probe_batch_size=500,
    )  # configs/cpu.yaml's data
    data.setup("fit")
    batch = next(iter(data.val_dataloader()))
    for variant in specs.STANDARD_VARIANTS["object_persistence"]:
        chosen = batch[batch["variant"] == specs.VARIANTS.index(variant)]
        for side in ("consistent", "inconsistent"):
            inputs = video_inputs(chosen, side)
            report(
                f"probe {variant}, {side}",
                landings(model, chosen[side, "frames"], inputs["objects"], inputs.get("camera")),
            )


if __name__ == "__main__":
    main()

"""Where solidity's counterbalanced violation happens, as the positive control sees it: at the
first frame at which a validation pair's two videos differ (the inconsistent block caught by the
hidden support), how far the block had fallen, how far it then moves, the control's mixture
weights for it (as its dynamics give them, before ``falling_lands`` leaves the stop out for a
falling block) and the surprise there and over each video, per checkpoint.

    python experiments/block_stop.py runs/r14_slow_s0/version_0/checkpoints/last.ckpt \
        --root data/cpu
"""

import argparse

import numpy as np
import torch

from datamodules import VOEDataModule
from voe_lightning import specs
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.base import video_inputs
from voe_lightning.model.likelihood import rectified_excess
from voe_lightning.model.object_state.state import STATE_SIZE


def rollout(model: ObjectStateModel, batch, side: str) -> dict:
    """The control's rollout of one side of the batch, with its mixture weights [B, T-1, S, K]
    (the dynamics' outputs, caught as they are made) and per-frame surprise [B, T]."""
    caught = []
    hook = model.dynamics.register_forward_hook(lambda _, __, out: caught.append(out))
    inputs = video_inputs(batch, side)
    observations = model._inputs(batch[side, "frames"], inputs["objects"], inputs.get("camera"))
    with torch.no_grad():
        out = model.rollout(observations)
    hook.remove()
    components = model.hparams.components
    start = components * 2 * STATE_SIZE
    logits = torch.stack([o[..., start : start + components] for o in caught], dim=1)
    return {
        "observations": observations,
        "weights": logits.softmax(-1),
        "state": rectified_excess(out["state"], out["state_entropy"]),
        "surprise": model._per_frame(out),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--root", default="data/cpu")
    args = parser.parse_args()
    torch.set_num_threads(1)
    data = VOEDataModule(
        concepts=["solidity"],
        root=args.root,
        train_examples=2000,
        val_pairs=24,
        test_pairs=200,
        generalization_pairs=100,
        probe_batch_size=500,
    )  # configs/cpu.yaml's data
    data.setup("fit")
    batch = next(iter(data.val_dataloader()))
    pairs = batch[batch["variant"] == specs.VARIANTS.index("counterbalanced")]
    for checkpoint in args.checkpoints:
        model = ObjectStateModel.load_from_checkpoint(checkpoint, map_location="cpu").eval()
        con, inc = (rollout(model, pairs, side) for side in ("consistent", "inconsistent"))
        rows = []
        for b in range(pairs.shape[0]):
            seen = con["observations"].visible[b]
            height = con["observations"].state[b, ..., 2]
            moved = ((height[1:] - height[:-1]).abs() * seen[1:] * seen[:-1]).sum(0)
            block = int(moved.argmax())  # the slot whose seen height changes most
            other = inc["observations"]
            differs = (seen[:, block] != other.visible[b, :, block]) | (
                (height[:, block] - other.state[b, :, block, 2]).abs() > 1e-4
            )
            t = int(torch.nonzero(differs)[0])
            rows.append(
                [
                    float(height[0, block] - height[t - 1, block]),
                    float(other.state[b, t - 1, block, 2] - other.state[b, t, block, 2]),
                    *inc["weights"][b, t - 1, block].tolist(),
                    float(inc["state"][b, t, block]),
                    float(con["surprise"][b, t]),
                    float(inc["surprise"][b, t]),
                    float(con["surprise"][b].sum()),
                    float(inc["surprise"][b].sum()),
                ]
            )
        r = np.array(rows).mean(0)
        k = model.hparams.components
        left_out = (
            "; falling_lands then leaves the stop out" if model.hparams.get("falling_lands") else ""
        )
        print(
            f"{checkpoint}: {len(rows)} pairs; the block fell {r[0]:.3f} m before the first "
            f"differing frame, the inconsistent one then {r[1]:.3f} m; its weights as the "
            f"dynamics give them (stop, move..., land{left_out}) "
            f"{np.round(r[2 : 2 + k], 2).tolist()}, its state surprise there "
            f"{r[2 + k]:.2f}; surprise at that frame {r[3 + k]:.2f} / {r[4 + k]:.2f}, over the "
            f"videos {r[5 + k]:.2f} / {r[6 + k]:.2f} (consistent / inconsistent)"
        )


if __name__ == "__main__":
    main()

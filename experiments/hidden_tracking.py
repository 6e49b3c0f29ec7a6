"""How well the positive control tracks what it cannot see: for each validation probe of a
concept, each hidden object's largest distance (m) between the control's belief and its true
hidden position (which the record keeps and the model never reads), per variant and video;
and, per term, the mean surprise (rectified excess surprisal summed over frames and objects).

    python experiments/hidden_tracking.py runs/ost_s3/version_0/checkpoints/last.ckpt \
        --concept containment --root data/cpu

``--set inertia=false`` evaluates the checkpoint with those constructor
arguments instead of its own (only ones that add no parameter load).
"""

import argparse

import numpy as np
import torch
import yaml

from voe_lightning import specs
from voe_lightning.datamodules import VOEDataModule
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.base import video_inputs
from voe_lightning.model.likelihood import rectified_excess
from voe_lightning.model.object_state.state import SLOT_TERMS


def largest_errors(model: ObjectStateModel, batch, side: str) -> list[float]:
    """Per hidden object of one side of a probe batch (seen before, then hidden), the largest
    distance between the model's belief and the true position over the frames it is hidden."""
    inputs = video_inputs(batch, side)
    observations = model._inputs(batch[side, "frames"], inputs["objects"], inputs.get("camera"))
    with torch.no_grad():
        belief = model.rollout(observations)["belief"][..., :3]
    position = inputs["objects"]["position"].float()
    ids = observations.ids[:, None, :, None].expand(-1, position.shape[1], -1, 3)
    truth = position.gather(2, ids)  # [B, T, S, 3]
    seen = observations.visible
    seen_before = seen.long().cummax(dim=1).values.bool()
    hidden = seen_before & ~seen
    error = (belief - truth).norm(dim=-1).masked_fill(~hidden, 0.0)  # [B, T, S]
    return error.amax(1)[hidden.any(1)].tolist()


def term_surprise(model: ObjectStateModel, batch, side: str) -> dict[str, float]:
    """Mean over the batch's videos of each term's surprise, summed over frames and objects."""
    inputs = video_inputs(batch, side)
    observations = model._inputs(batch[side, "frames"], inputs["objects"], inputs.get("camera"))
    with torch.no_grad():
        out = model.rollout(observations)
    terms = {
        name: rectified_excess(out[name], out[f"{name}_entropy"]).sum((1, 2)) for name in SLOT_TERMS
    }
    terms["appear"] = rectified_excess(out["appear"], out["appear_entropy"]).sum(1)
    return {name: float(value.mean()) for name, value in terms.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--concept", default="containment", choices=specs.CONCEPTS)
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a constructor argument to use instead of the checkpoint's",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    overrides = {
        name: yaml.safe_load(value)  # true -> True, 0.5 -> 0.5, none -> "none"
        for name, value in (setting.split("=", 1) for setting in args.set)
    }
    model = ObjectStateModel.load_from_checkpoint(
        args.checkpoint, map_location="cpu", **overrides
    ).eval()
    data = VOEDataModule(
        concepts=[args.concept],
        root=args.root,
        train_examples=2000,
        val_pairs=24,
        test_pairs=200,
        generalization_pairs=100,
        probe_batch_size=500,
    )  # configs/cpu.yaml's data
    data.setup("fit")
    for batch in data.val_dataloader():
        for variant in specs.STANDARD_VARIANTS.get(args.concept, ()):
            chosen = batch[batch["variant"] == specs.VARIANTS.index(variant)]
            for side in ("consistent", "inconsistent"):
                errors = largest_errors(model, chosen, side)
                terms = term_surprise(model, chosen, side)
                print(
                    f"{variant:15s} {side:12s} hidden objects {len(errors):3d}, largest "
                    f"belief error: median {np.median(errors) if errors else float('nan'):.2f} m"
                    " | surprise " + " ".join(f"{k} {v:.1f}" for k, v in terms.items())
                )


if __name__ == "__main__":
    main()

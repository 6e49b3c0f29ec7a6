"""What the pixel rung expected: a consistent probe video of the fresh set (top) and, below it,
the trained rung's expected frame at every other frame (``ObjectStateModel.expected_frames``:
the expected codes decoded over the frame before's background). It shows how coarse the
learned encoder's codes are.

    python experiments/pixel_rung_expected.py runs/learned_pixels/version_0/checkpoints/last.ckpt \
        --out docs/images/pixel_rung_expected.png
"""

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

from voe_lightning.model import ObjectStateModel
from voe_lightning.scenes import generate_probe


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--concept", default="containment")
    parser.add_argument("--seed", type=int, default=6000005, help="a fresh-set probe seed")
    parser.add_argument("--out", default="pixel_rung_expected.png")
    args = parser.parse_args()
    model = ObjectStateModel.load_from_checkpoint(args.checkpoint, map_location="cpu").eval()
    probe = generate_probe(args.concept, "standard", args.seed)
    video, camera = probe["consistent"], probe["camera"][None]
    frames, mask = video["frames"][None], video["mask"][None]
    with torch.no_grad():
        expected = model.expected_frames(frames, mask, camera)[0]
    shown = range(0, frames.shape[1], 2)
    figure, axes = plt.subplots(2, len(shown), figsize=(2 * len(shown), 4))
    for column, t in enumerate(shown):
        axes[0, column].imshow(frames[0, t].numpy())
        axes[1, column].imshow(expected[t].permute(1, 2, 0).clamp(0, 1).numpy())
        axes[0, column].set_title(f"t={t}")
        for row in (0, 1):
            axes[row, column].axis("off")
    axes[0, 0].text(-8, 32, "seen", rotation=90, va="center", ha="right")
    axes[1, 0].text(-8, 32, "expected", rotation=90, va="center", ha="right")
    figure.tight_layout()
    figure.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

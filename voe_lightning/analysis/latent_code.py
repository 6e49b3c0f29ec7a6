"""How many of a VRNN-LRU's latents carry information: KL(posterior || prior) per latent on a
store's videos (``python -m voe_lightning analyze latents``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from voe_lightning import specs
from voe_lightning.analysis.training_curves import labelled_run
from voe_lightning.data.store import collate, open_split, read_manifest
from voe_lightning.model import VRNNLRUModel


def latent_usage(
    model: VRNNLRUModel, frames: torch.Tensor, threshold: float = 0.01
) -> dict[str, Any]:
    """How much of ``model``'s latent code carries information on uint8 videos ``frames``: batch
    means of KL(posterior || prior) per sequence, of the first frame and per later frame, and the
    latents whose KL per later frame averages above ``threshold`` nats (the rest sit on the
    prior: posterior collapse)."""
    per_latent = model.latent_kl(frames).mean(dim=0)  # [T, latents]
    later = per_latent[1:].mean(dim=0)
    return {
        "kl_per_sequence": per_latent.sum().item(),
        "first_frame": per_latent[0].sum().item(),
        "per_later_frame": per_latent[1:].sum(dim=-1).mean().item(),
        "latents_in_use": int((later > threshold).sum()),
        "latents": later.numel(),
    }


def latents(
    checkpoints: list[str],
    root: Path,
    pairs: int = 16,
    threshold: float = 0.01,
    out: Path | None = None,
) -> str:
    """How many latents of VRNN-LRU checkpoints carry information, as a Markdown table: KL per
    sequence, of the first frame and per later frame, and the latents above ``threshold``, on
    the consistent videos of the first ``pairs`` test pairs of each concept in ``root``.

    Args:
        checkpoints: VRNN-LRU checkpoints as [LABEL=]PATH.
        root: a generated store whose frames have the checkpoints' image size.
        pairs: test pairs read per concept.
        threshold: nats per frame above which a latent counts as in use.
        out: also write the table here.
    """
    if pairs < 1 or threshold < 0:
        raise ValueError(f"pairs must be >= 1 and threshold >= 0, got {pairs} and {threshold}")
    manifest = read_manifest(root)
    if manifest is None:
        raise FileNotFoundError(f"no store at {root} (no manifest.json): generate it first")
    videos = []
    for concept in (c for c in specs.CONCEPTS if c in manifest["concepts"]):
        split = open_split(root, concept, "test")
        videos.append(
            collate([split[i] for i in range(min(pairs, len(split)))])["consistent", "frames"]
        )
    frames = torch.cat(videos)
    lines = [
        "| checkpoint | KL / sequence | first frame | per later frame | latents in use |",
        "|---|---|---|---|---|",
    ]
    for label, path in map(labelled_run, checkpoints):
        model = VRNNLRUModel.load_from_checkpoint(path, map_location="cpu", weights_only=True)
        model.eval()
        usage = latent_usage(model, frames, threshold)
        lines.append(
            f"| {label} | {usage['kl_per_sequence']:.1f} | {usage['first_frame']:.1f} | "
            f"{usage['per_later_frame']:.2f} | "
            f"{usage['latents_in_use']} of {usage['latents']} |"
        )
    table = (
        "\n".join(lines) + f"\n\n{len(frames)} consistent test videos of {root}; in use: "
        f"more than {threshold:g} nats per frame after the first.\n"
    )
    print(table, end="")
    if out:
        Path(out).write_text(table)
    return table

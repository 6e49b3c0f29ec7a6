"""The example videos of a ``test`` report's figures: inconsistent probes for
predictions_<concept>.png (the model's ``expected_frames``) and object-persistence pairs for
tsne_object_persistence.png (its ``trajectories``), kept batch by batch and run through the
model once the test is over (``ExampleVideos``)."""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import torch
from lightning.pytorch.utilities import rank_zero_warn

from voe_lightning.model.base import SurpriseModel, expected_frames_problem, video_inputs
from voe_lightning.report.figures import PredictionExample, tsne_unfit

#: Kept videos per (concept, variant) index for the predictions, per variant index for t-SNE.
Kept = tuple[dict[tuple[int, int], list[dict[str, Any]]], dict[int, list[dict[str, Any]]]]


def _stacked(videos: list[dict[str, Any]], device: torch.device) -> dict[str, Any]:
    """Kept videos (frames and, where the batch had them, mask and camera) as one batch."""
    return {key: torch.stack([video[key] for video in videos]).to(device) for key in videos[0]}


class ExampleVideos:
    """Keeps up to ``max_prediction_examples`` inconsistent probes per concept/variant and
    ``tsne_pairs`` object-persistence pairs per variant (``kept``, on the CPU); the figures
    take them standard and counterbalanced alternately, up to ``tsne_pairs`` in all. Names are
    decoded with the DataModule's ``concept_names`` / ``variant_names``."""

    def __init__(
        self,
        max_prediction_examples: int,
        tsne_pairs: int,
        concept_names: Sequence[str],
        variant_names: Sequence[str],
    ) -> None:
        self.max_prediction_examples, self.tsne_pairs = max_prediction_examples, tsne_pairs
        self.concept_names, self.variant_names = concept_names, variant_names
        self.kept: Kept = ({}, {})

    def add(self, stored: Mapping[str, np.ndarray], batch: Any, read: Collection[str] = ()) -> None:
        """Keep what is still wanted of a batch whose probe outputs are ``stored``, with the
        inputs a model that reads ``read`` is given (``video_inputs``)."""
        examples, tsne_pairs = self.kept
        persistence = (
            self.concept_names.index("object_persistence")
            if "object_persistence" in self.concept_names
            else None
        )
        for i, (concept, variant) in enumerate(zip(stored["concept"], stored["variant"])):
            concept, variant = int(concept), int(variant)
            meta = {
                "concept": concept,
                "variant": variant,
                "seed": int(stored["seed"][i]),
                "manipulation_frame": int(stored["manipulation_frame"][i]),
            }
            kept = examples.setdefault((concept, variant), [])
            videos = {
                side: {"frames": batch[side, "frames"][i].cpu().clone()}
                | {
                    name: value[i].cpu().clone()
                    for name, value in video_inputs(batch, side, read).items()
                }
                for side in ("consistent", "inconsistent")
            }
            if len(kept) < self.max_prediction_examples:
                kept.append(meta | {"inconsistent": videos["inconsistent"]})
            tsne = tsne_pairs.setdefault(variant, []) if concept == persistence else None
            if tsne is not None and len(tsne) < self.tsne_pairs:
                tsne.append(meta | videos)

    def figure_inputs(
        self, pl_module: SurpriseModel, gathered: Iterable[Kept]
    ) -> tuple[list[PredictionExample], dict[str, Any] | None, list[str] | None]:
        """Every rank's ``kept`` videos (``gathered``) run through the model in eval mode
        without gradients: the prediction examples, the t-SNE trajectories and their labels
        (None, None, with a warning, for fewer than two pairs or courses t-SNE cannot embed)."""
        examples, tsne = [], []
        for rank_examples, rank_tsne in gathered:
            examples += [e for kept in rank_examples.values() for e in kept]
            tsne += [e for kept in rank_tsne.values() for e in kept]
        was_training = pl_module.training
        pl_module.eval()
        try:
            with torch.no_grad():
                predictions = self._predictions(pl_module, examples)
                trajectories, labels = self._trajectories(pl_module, tsne)
        finally:
            pl_module.train(was_training)
        return predictions, trajectories, labels

    def _predictions(
        self, pl_module: SurpriseModel, examples: list[dict[str, Any]]
    ) -> list[PredictionExample]:
        if not examples:
            return []
        video = _stacked([e["inconsistent"] for e in examples], pl_module.device)
        returned = pl_module.expected_frames(**video)
        if problem := expected_frames_problem(pl_module, returned, video["frames"]):
            rank_zero_warn(f"{problem}; predictions_<concept>.png not written")
            return []
        expected = returned.float().cpu().numpy()
        return [
            PredictionExample(
                concept=self.concept_names[e["concept"]],
                variant=self.variant_names[e["variant"]],
                seed=e["seed"],
                manipulation_frame=e["manipulation_frame"],
                frames=e["inconsistent"]["frames"].numpy(),
                expected=expected[i],
            )
            for i, e in enumerate(examples)
        ]

    def _trajectories(
        self, pl_module: SurpriseModel, tsne: list[dict[str, Any]]
    ) -> tuple[dict[str, Any] | None, list[str] | None]:
        # Interleave variants (standard, counterbalanced, standard, ...) up to tsne_pairs.
        by_variant: dict[int, list[dict[str, Any]]] = {}
        for e in tsne:
            by_variant.setdefault(e["variant"], []).append(e)
        order = sorted(by_variant, key=lambda v: self.variant_names[v] != "standard")
        chosen = [
            by_variant[v][i]
            for i in range(self.tsne_pairs)
            for v in order
            if i < len(by_variant[v])
        ][: self.tsne_pairs]
        if len(chosen) < 2:
            if self.tsne_pairs:
                _skip_tsne("fewer than 2 object-persistence probe pairs in the test set")
            return None, None
        trajectories = {}
        for video in ("consistent", "inconsistent"):
            courses = pl_module.trajectories(
                **_stacked([e[video] for e in chosen], pl_module.device)
            )
            trajectories[video] = {k: v.float().cpu().numpy() for k, v in courses.items()}
        if reason := tsne_unfit(trajectories):
            _skip_tsne(reason)
            return None, None
        labels = [f"{self.variant_names[e['variant']]} (seed {e['seed']})" for e in chosen]
        return trajectories, labels


def _skip_tsne(reason: str) -> None:
    """Warn that the t-SNE figure is left out, and why; the report is written without it."""
    rank_zero_warn(f"{reason}; tsne_object_persistence.png not written")

"""The DeepMind Physical Concepts dataset (Piloto et al. 2022) as a LightningDataModule:
freeform clips for training and the five concepts' probe quadruplets for evaluation; the
reading (TFRecords, without TensorFlow) is ``reader``, beside it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torch.utils.data import DataLoader, Dataset, IterableDataset, Subset
from tqdm import tqdm

from voe_lightning.benchmarks.cache import CachedRecords, fingerprint, open_cache, write_cache
from voe_lightning.benchmarks.datamodule import ExternalDataModule
from voe_lightning.benchmarks.external_pairs import ExternalPairs
from voe_lightning.benchmarks.physical_concepts.reader import (
    CONCEPT_NAMES,
    NUM_FRAMES,
    PROBE_CONCEPTS,
    RECORD_VERSION,
    SHARD_STRIDE,
    VARIANT_NAMES,
    RecordStream,
    Source,
    chain,
    part_sources,
)
from voe_lightning.benchmarks.reader import SkipLog, worker_loader
from voe_lightning.datamodule_arguments import check_at_least, check_fraction


class PhysicalConceptsDataModule(ExternalDataModule):
    """Trains on ``freeform/train`` clips and probes ``probes/<concept>`` for every concept in
    ``concepts``, so ``fit`` and ``test`` work as on our own data. The release has one probe set
    per concept: validation during ``fit`` uses the first ``val_quadruplets_per_concept``
    quadruplets of each concept's first shard, both pairs of each, streamed or cached (for
    monitoring; the test uses all of them).

    Args:
        root: folder holding ``freeform/`` and ``probes/``.
        concepts: probe concepts to evaluate (of continuity, solidity, object_persistence,
            unchangeableness, directional_inertia).
        batch_size: clips per training batch.
        probe_batch_size: probe pairs per evaluation batch.
        num_workers: DataLoader worker processes (shards are split between them).
        num_frames, height, width: model input geometry (the release is 15 x 64 x 64).
            None (default): the model's, resolved in ``setup`` (its ``training_frames`` and
            ``image_size`` hyperparameters, from the checkpoint under ``test --ckpt_path``).
        frame_stride, first_frame: sample every ``frame_stride``-th frame from ``first_frame``;
            by default ``num_frames`` frames spread evenly over the 15.
        divergence_level, divergence_fraction: a frame differs when more than this fraction of
            its pixels differ by more than this many grey levels.
        val_quadruplets_per_concept: probe quadruplets per concept in the validation set.
        shuffle_buffer: records in the training shuffle buffer when streaming (no cache).
        lenient: skip corrupt shards/records instead of raising; ``skipped`` counts them.
        cache_dir: if set, decoded records are written there once (store shards) and every
            epoch reads them instead of the TFRecords (map-style, fully shuffled).
        seed: seed of the training order.
    """

    concept_names, variant_names = CONCEPT_NAMES, VARIANT_NAMES
    source_frames = NUM_FRAMES

    def __init__(
        self,
        root: str = "data/physical_concepts",
        concepts: list[str] = list(PROBE_CONCEPTS),  # noqa: B006 (the CLI reads it; never mutated)
        batch_size: int = 10,
        probe_batch_size: int = 32,
        num_workers: int = 0,
        num_frames: int | None = None,
        height: int | None = None,
        width: int | None = None,
        frame_stride: int | None = None,
        first_frame: int = 0,
        divergence_level: int = 10,
        divergence_fraction: float = 0.001,
        val_quadruplets_per_concept: int = 50,
        shuffle_buffer: int = 256,
        lenient: bool = False,
        cache_dir: str | None = None,
        seed: int = 0,
    ):
        super().__init__()
        unknown = [c for c in concepts if c not in PROBE_CONCEPTS]
        if unknown or not concepts:
            raise ValueError(
                f"unknown or no probe concepts {unknown}; valid concepts are: {', '.join(PROBE_CONCEPTS)}"
            )
        check_at_least(
            {
                "batch_size": (batch_size, 1),
                "probe_batch_size": (probe_batch_size, 1),
                "height": (height, 1),
                "width": (width, 1),
                "val_quadruplets_per_concept": (val_quadruplets_per_concept, 1),
                "num_workers": (num_workers, 0),
                "num_frames": (num_frames, 1),
                "frame_stride": (frame_stride, 1),
                "first_frame": (first_frame, 0),
                "divergence_level": (divergence_level, 0),
                "shuffle_buffer": (shuffle_buffer, 0),
            }
        )
        check_fraction("divergence_fraction", divergence_fraction)
        self.save_hyperparameters()
        self.concepts = list(dict.fromkeys(concepts))
        self._resolve_video(required=False)
        self._datasets: dict[str, Dataset[TensorDict]] = {}

    # --- building --------------------------------------------------------------------------------
    def _sources(self, part: str) -> list[Source]:
        """Shards of ``part`` (see ``part_sources``); with ``lenient``, missing ones are counted."""
        skips = self._skips.setdefault(part, SkipLog())
        skip = (
            (lambda error: skips.add(error.reason, str(error))) if self.hparams["lenient"] else None
        )
        return part_sources(self.hparams["root"], part, skip)

    def _dataset(self, part: str, shuffle: bool = False) -> Dataset[TensorDict]:
        """All records of ``part``: from the cache (built on first use) if ``cache_dir`` is
        set, else streamed from the shards."""
        key = f"{part}|{shuffle}"
        if key in self._datasets:
            return self._datasets[key]
        h = self.hparams
        sources = self._sources(part)
        skips = self._skips[part]
        dataset: Dataset[TensorDict]
        if h["cache_dir"] is None:
            dataset = RecordStream(
                sources,
                self.video,
                h["lenient"],
                skips,
                shuffle=shuffle,
                shuffle_buffer=h["shuffle_buffer"] if shuffle else 0,
                seed=h["seed"],
            )
        else:
            settings = {
                "part": part,
                "video": self.video.__dict__,
                "lenient": h["lenient"],
                "records": RECORD_VERSION,
            }
            folder = (
                Path(h["cache_dir"])
                / "physical_concepts"
                / part
                / fingerprint(settings, [s.path for s in sources])
            )
            cached = open_cache(folder, {"skipped": dict})
            if cached is None:
                meta: dict[str, Any] = {}
                records = self._convert(sources, meta, skips, part)
                spec = self.clip_spec() if part in ("train", "test") else self.probe_spec()
                cached = write_cache(folder, records, spec, meta)
            self._skips[part] = SkipLog()  # the cache's counts include this scan's
            self._cached_skips[part] = cached.meta.get("skipped", {})
            dataset = cached
        self._datasets[key] = dataset
        return dataset

    def _convert(
        self, sources: list[Source], meta: dict[str, Any], skips: SkipLog, part: str
    ) -> Iterator[TensorDict]:
        stream = RecordStream(sources, self.video, self.hparams["lenient"], skips)
        loader = worker_loader(stream, self.hparams["num_workers"])
        yield from tqdm(
            loader, desc=f"caching Physical Concepts {part}", unit="record", leave=False
        )
        meta["skipped"] = skips.counts()

    def _validation_set(self, concept: str) -> Dataset[TensorDict]:
        h = self.hparams
        limit = h["val_quadruplets_per_concept"]
        if h["cache_dir"] is not None:  # worker processes interleave shards: select by seed
            dataset = self._dataset(f"probes/{concept}")
            assert isinstance(dataset, CachedRecords)  # cache_dir: the cache's records
            shard, record = np.divmod(dataset.seeds(), SHARD_STRIDE)
            first = shard.min(initial=np.iinfo(np.int64).max)
            return Subset(dataset, np.flatnonzero((shard == first) & (record < limit)).tolist())
        part = f"probes/{concept}"
        sources = self._sources(part)[:1]
        return RecordStream(
            sources, self.video, h["lenient"], self._skips[part], limit_per_source=limit
        )

    def setup(self, stage: str | None = None) -> None:
        self._resolve_video()
        if stage in ("fit", None):
            self._dataset("train", shuffle=True)
        if stage in ("fit", "validate", None):
            for concept in self.concepts:
                self._validation_set(concept)
        if stage in ("test", None):
            for concept in self.concepts:
                self._dataset(f"probes/{concept}")

    def probe_cases(self, split: str = "val") -> list[tuple[str, str]]:
        return [(concept, variant) for concept in self.concepts for variant in VARIANT_NAMES]

    # --- loaders ---------------------------------------------------------------------------------
    def train_dataloader(self) -> DataLoader[TensorDict]:
        dataset = self._dataset("train", shuffle=True)
        if isinstance(dataset, IterableDataset):
            return self._loader(dataset, self.hparams["batch_size"], drop_last=True)
        generator = torch.Generator().manual_seed(self.hparams["seed"])
        return self._loader(
            dataset, self.hparams["batch_size"], shuffle=True, drop_last=True, generator=generator
        )

    def val_dataloader(self) -> DataLoader[TensorDict]:
        return self._loader(
            chain([self._validation_set(c) for c in self.concepts]),
            self.hparams["probe_batch_size"],
        )

    def test_dataloader(self) -> DataLoader[TensorDict]:
        return self._loader(
            chain([self._dataset(f"probes/{c}") for c in self.concepts]),
            self.hparams["probe_batch_size"],
        )

    # --- evaluation ------------------------------------------------------------------------------
    def external_pairs(self) -> ExternalPairs:
        """The concept names and skipped counts, for the per-concept quadruplet metrics
        (``voe_lightning.benchmarks.evaluation``); a pair's quadruplet is its ``seed``."""
        return ExternalPairs("DeepMind Physical Concepts", self.concept_names, skipped=self.skipped)

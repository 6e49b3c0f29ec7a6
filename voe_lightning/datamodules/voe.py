"""The DataModule behind the per-concept and joint regimes: it generates any missing data in
``prepare_data``, trains on examples + controls interleaved with equal counts per concept, and
serves validation (during ``fit``) and test probe pairs (for ``test``) from the store, or, with
a ``seed_offset``, from a fresh draw of them in the store's ``seed_offset_<N>`` folder."""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence, Sized
from pathlib import Path
from typing import Any, cast, get_args

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torch.utils.data import ConcatDataset, DataLoader, Dataset, Sampler, Subset

from voe_lightning import specs
from voe_lightning.data import store
from voe_lightning.data.store import (
    SplitDataset,
    check_seed_offset,
    ensure_dataset,
    open_split,
    probe_sampler,
    record_loader,
    store_root,
)
from voe_lightning.datamodule_arguments import check_at_least
from voe_lightning.datamodules.resident import ResidentBatches, resident_records
from voe_lightning.probe_datamodule import ProbeDataModule


class InterleavedSampler(Sampler[int]):
    """Indices into a ConcatDataset that alternate between its parts, the same number from each
    part per epoch (the shortest part's length), shuffled per part with a seed and the epoch."""

    def __init__(self, lengths: Sequence[int], shuffle: bool = True, seed: int = 0):
        if not lengths or min(lengths) == 0:
            raise ValueError(f"every part needs at least one record, got lengths {list(lengths)}")
        self.lengths, self.shuffle, self.seed, self.epoch = list(lengths), shuffle, seed, 0
        self.offsets = np.cumsum([0] + self.lengths[:-1])

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return min(self.lengths) * len(self.lengths)

    def __iter__(self) -> Iterator[int]:
        rng = np.random.default_rng([self.seed, self.epoch])
        per_part = min(self.lengths)
        columns = []
        for length, offset in zip(self.lengths, self.offsets):
            order = rng.permutation(length) if self.shuffle else np.arange(length)
            columns.append(order[:per_part] + offset)
        interleaved = np.stack(columns, axis=1)  # [per_part, parts]: row i = one of each part
        if self.shuffle:  # vary which concept comes first within each round
            interleaved = rng.permuted(interleaved, axis=1)
        self.epoch += 1
        return iter(interleaved.reshape(-1).tolist())


#: ``specs.CONCEPTS`` typed as concepts: the default of ``VOEDataModule``'s ``concepts``.
_CONCEPTS: tuple[specs.Concept, ...] = get_args(specs.Concept)

#: The probe splits ``test`` can report on (``VOEDataModule``'s ``test_split``).
TEST_SPLITS = ("test", "val")


class VOEDataModule(ProbeDataModule):
    """Examples + controls of ``concepts`` for training (equal counts per concept, interleaved),
    their validation probe pairs for ``fit`` and test probe pairs (plus the generalization probes
    if ``generalization``) for ``test``. Missing data is generated under ``root`` on first use.
    With the default ``concepts`` (all five) it is the paper's jointly trained model's data.

    Args:
        concepts: which of the five concepts to use.
        root: dataset directory (created and filled by ``prepare_data`` if incomplete).
        train_examples: consistent training examples per concept.
        train_controls: controls per concept, split evenly over the control kinds (default:
            as many as examples, the paper's 1:1).
        val_pairs: validation probe pairs per concept and variant.
        test_pairs: test probe pairs per concept and variant.
        generalization_pairs: generalization probe pairs per concept and variant.
        generalization: also test on the generalization probes (paper §5).
        batch_size: clips per training batch (the paper used 10).
        probe_batch_size: probe pairs per evaluation batch.
        num_workers: DataLoader worker processes.
        train_on_device: hold the training clips (their ``train_fields``; default the frames,
            as uint8) on the training device and gather each batch there
            (``voe_lightning.datamodules.resident``): for a GPU training thousands of sequences a second.
        train_fields: the record fields of each training batch, read once and held whole
            (on the training device with ``train_on_device``, else in host memory), so no batch
            decodes a record; None: whole records through the DataLoader. The state learner
            reads ``[objects, camera]``: no frame is decoded after the first pass; its mask
            rung ``[mask_features, camera]``: what each clip's mask and frames show of each
            id, measured once as the clips are read (``resident.MASK_FEATURES``).
        generate_workers: processes rendering missing data (default: all cores).
        num_frames, height, width: video geometry (paper: 15 frames of 64x64).
        seed: seed of the training order.
        test_split: the probe split ``test`` reports on: ``"test"`` (the final report) or
            ``"val"`` (the validation probes' quadruplets, for tuning; generalization probes
            are then left out), in a report folder of its own.
        seed_offset: draw the validation, test and generalization probes this far into their
            splits' seed ranges (0: the store's own): a fresh test set of any size no one has
            seen, generated or read in ``root/seed_offset_<N>`` (``store.seed_offset_root``,
            probes only), so the training data's store is never touched; the report names it.
        train_limit: train on only the first ``train_limit`` examples per concept of the store
            (and their controls in proportion: the plan interleaves the kinds, so every prefix
            holds them so); None: all ``train_examples``. A training-size sweep over one store.
    """

    concept_names, variant_names = specs.CONCEPTS, specs.VARIANTS

    def __init__(
        self,
        concepts: list[specs.Concept] = list(_CONCEPTS),  # noqa: B006 (the CLI reads it; never mutated)
        root: str = "data/voe",
        train_examples: int = 1000,
        train_controls: int | None = None,
        val_pairs: int = 32,
        test_pairs: int = 128,
        generalization_pairs: int = 64,
        generalization: bool = False,
        batch_size: int = 10,
        probe_batch_size: int = 32,
        num_workers: int = 0,
        train_on_device: bool = False,
        generate_workers: int | None = None,
        num_frames: int = specs.NUM_FRAMES,
        height: int = specs.HEIGHT,
        width: int = specs.WIDTH,
        seed: int = 0,
        seed_offset: int = 0,
        test_split: str = "test",
        train_limit: int | None = None,
        train_fields: list[str] | None = None,
    ):
        super().__init__()
        if test_split not in TEST_SPLITS:
            raise ValueError(
                f"test_split must be one of {TEST_SPLITS} (the probes test reports on), "
                f"got {test_split!r}"
            )
        if not concepts:
            raise ValueError(f"concepts must name at least one of: {', '.join(specs.CONCEPTS)}")
        for concept in concepts:
            specs.check_concept(concept)
        check_at_least(
            {
                "train_examples": (train_examples, 1),
                "train_controls": (train_controls, 0),
                "val_pairs": (val_pairs, 1),
                "test_pairs": (test_pairs, 1),
                "generalization_pairs": (generalization_pairs, 1 if generalization else 0),
                "batch_size": (batch_size, 1),
                "probe_batch_size": (probe_batch_size, 1),
                "num_workers": (num_workers, 0),
                "generate_workers": (generate_workers, 1),
                "num_frames": (num_frames, 2),
                "height": (height, 1),
                "width": (width, 1),
                "seed": (seed, 0),
            }
        )
        if train_limit is not None and not 1 <= train_limit <= train_examples:
            raise ValueError(
                f"train_limit must be a number of examples per concept from 1 to train_examples "
                f"({train_examples}), or None for all; got {train_limit!r}"
            )
        if train_fields is not None and not train_fields:
            raise ValueError(
                "train_fields must name at least one record field (e.g. [objects, camera]), "
                "or be None for whole records"
            )
        check_seed_offset(
            seed_offset,
            {"val": val_pairs, "test": test_pairs, "generalization": generalization_pairs},
        )
        self.save_hyperparameters()
        self.concepts = list(dict.fromkeys(concepts))
        self._datasets: dict[str, ConcatDataset[TensorDict] | None] = {}
        self._resident: TensorDictBase | None = None

    # --- data on disk --------------------------------------------------------------------------
    def _generation_arguments(self, split: str) -> dict[str, Any]:
        """``ensure_dataset``'s arguments for the store ``split`` is in (``_store_root``): the
        seed offset's, which holds no training clips, for a probe split."""
        h = self.hparams
        seed_offset = 0 if split == "train" else h["seed_offset"]
        train_controls = h["train_examples"] if h["train_controls"] is None else h["train_controls"]
        return dict(
            concepts=self.concepts,
            seed_offset=seed_offset,
            train_examples=0 if seed_offset else h["train_examples"],
            train_controls=0 if seed_offset else train_controls,
            val_pairs=h["val_pairs"],
            test_pairs=h["test_pairs"],
            generalization_pairs=h["generalization_pairs"],
            workers=h["generate_workers"] or os.cpu_count() or 1,
            num_frames=h["num_frames"],
            height=h["height"],
            width=h["width"],
        )

    def _probe_splits(self, stage: str | None) -> list[str] | None:
        """The probe splits ``validate`` or ``test`` reads (None for other stages)."""
        by_stage: dict[str | None, list[str]] = {
            "validate": ["val"],
            "test": [self.hparams["test_split"]],
        }
        splits = by_stage.get(stage)
        if (
            splits is not None
            and stage == "test"
            and self.hparams["generalization"]
            and self.hparams["test_split"] == "test"
        ):
            splits.append("generalization")
        return splits

    def _store_root(self, split: str) -> Path:
        """The store ``split`` is read from (``store.store_root``)."""
        root = store_root(self.hparams, split)
        assert root is not None, "a VOEDataModule always has a root"
        return root

    def probe_source(self) -> dict[str, Any]:
        """The data root, the seed offset and the store its probes are read from."""
        return {
            **super().probe_source(),
            "seed_offset": self.hparams["seed_offset"],
            "probe_root": str(self._store_root("test")),
            "probe_split": self.hparams["test_split"],
        }

    def prepare_data(self) -> None:
        """Generate whatever part of the dataset is missing (a no-op when complete): under a
        ``validate`` or ``test`` only its probe splits, so a mistyped root costs no train split;
        with a seed offset, the probe splits into their own store (``_store_root``)."""
        trainer = self.trainer
        stage = trainer.state.fn.value if trainer is not None and trainer.state.fn else None
        splits = self._probe_splits(stage) or store.SPLITS
        by_store: dict[Path, list[str]] = {}
        for split in splits:
            by_store.setdefault(self._store_root(split), []).append(split)
        for store_splits in by_store.values():
            ensure_dataset(
                self.hparams["root"],
                splits=store_splits,
                **self._generation_arguments(store_splits[0]),
            )

    def setup(self, stage: str | None = None) -> None:
        splits = self._probe_splits(stage) or (
            ["train", "val"] if stage == "fit" else ["train", "val", "test"]
        )
        for split in splits:
            if split in self._datasets:
                continue
            parts = [
                self._limited(open_split(self._store_root(split), concept, split), split)
                for concept in self.concepts
                if split != "generalization" or specs.GENERALIZATION_VARIANTS[concept]
            ]
            self._datasets[split] = ConcatDataset(parts) if parts else None

    def _limited(self, part: SplitDataset, split: str) -> Dataset[TensorDict]:
        """A concept's split, cut to its first ``train_limit`` examples' worth of training clips."""
        limit = self.hparams["train_limit"]
        if split != "train" or limit is None:
            return part
        return Subset(part, range(round(len(part) * limit / self.hparams["train_examples"])))

    def probe_cases(self, split: str = "val") -> list[tuple[str, str]]:
        """The (concept, variant) pairs whose probes ``split`` holds."""
        variants = (
            specs.GENERALIZATION_VARIANTS if split == "generalization" else specs.STANDARD_VARIANTS
        )
        return [(c, v) for c in self.concepts for v in variants[c]]

    # --- loaders --------------------------------------------------------------------------------
    def _loader(
        self, dataset: Dataset[TensorDict], batch_size: int, **kwargs: Any
    ) -> DataLoader[TensorDict]:
        return record_loader(dataset, batch_size, self.hparams["num_workers"], **kwargs)

    def train_dataloader(self) -> DataLoader[TensorDict] | ResidentBatches:
        dataset = self._datasets["train"]
        assert dataset is not None  # every concept has training clips
        sampler = InterleavedSampler(
            [len(cast(Sized, part)) for part in dataset.datasets],  # _limited's SplitDataset/Subset
            shuffle=True,
            seed=self.hparams["seed"],
        )
        h = self.hparams
        if not h["train_on_device"] and h["train_fields"] is None:
            return self._loader(dataset, h["batch_size"], sampler=sampler, drop_last=True)
        if self._resident is None:
            trainer = self.trainer if h["train_on_device"] else None
            device = trainer.strategy.root_device if trainer is not None else torch.device("cpu")
            fields = h["train_fields"] or ["frames"]
            self._resident = resident_records(dataset, fields, device, h["num_workers"])
        return ResidentBatches(self._resident, sampler, h["batch_size"])

    def _probe_loader(self, split: str) -> DataLoader[TensorDict]:
        # Its own generator: a loader's iterator draws a seed, and drawing it from the global
        # RNG would make training depend on how often validation runs.
        generator = torch.Generator().manual_seed(self.hparams["seed"])
        batch_size = self.hparams["probe_batch_size"]
        dataset = self._datasets[split]
        assert dataset is not None  # test_dataloader reads generalization only where it has probes
        return self._loader(
            dataset, batch_size, generator=generator, sampler=probe_sampler(dataset)
        )

    def val_dataloader(self) -> DataLoader[TensorDict]:
        return self._probe_loader("val")

    def test_dataloader(self) -> DataLoader[TensorDict] | list[DataLoader[TensorDict]]:
        loaders = [self._probe_loader(self.hparams["test_split"])]
        if (
            "generalization" in (self._probe_splits("test") or [])
            and self._datasets.get("generalization") is not None
        ):
            loaders.append(self._probe_loader("generalization"))
        return loaders if len(loaders) > 1 else loaders[0]


class ConceptDataModule(VOEDataModule):
    """One concept: the paper's separately trained models."""

    def __init__(self, concept: specs.Concept = "object_persistence", **kwargs: Any) -> None:
        specs.check_concept(concept)
        super().__init__(concepts=[concept], **kwargs)

"""IntPhys (Riochet et al. 2018) as a LightningDataModule: training movies as clips, the
labelled dev quadruplets as probe pairs, and single movies for ``predict`` (answer.txt, see
``voe_lightning.callbacks.prediction_writer``); the reading is ``reader``, beside it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from voe_lightning.benchmarks.cache import fingerprint, open_cache, write_cache
from voe_lightning.benchmarks.datamodule import ExternalDataModule
from voe_lightning.benchmarks.external_pairs import ExternalPairs
from voe_lightning.benchmarks.intphys.reader import (
    BLOCKS,
    CONCEPT_NAMES,
    RECORD_VERSION,
    VARIANT_NAMES,
    Movie,
    MovieDataset,
    QuadrupletDataset,
    TrainClipDataset,
    frame_file,
    scan_quadruplets,
    scan_train,
)
from voe_lightning.benchmarks.reader import SkipLog, worker_loader
from voe_lightning.datamodule_arguments import check_at_least, check_fraction


class IntPhysDataModule(ExternalDataModule):
    """IntPhys for ``fit`` (training movies of ``train/`` as clips, dev probes for validation),
    ``validate``/``test`` (probe pairs of ``eval_split``, default the labelled dev set) and
    ``predict`` (single movies of ``predict_split``, default the unlabelled test set, scored
    into answer.txt by ``voe_lightning.callbacks.prediction_writer.IntPhysAnswerWriter``).

    Args:
        root: folder holding ``dev/``, ``test/`` and optionally ``train/``.
        batch_size: clips per training batch.
        probe_batch_size: probe pairs (or movies) per evaluation batch.
        num_workers: DataLoader worker processes (also used to decode the probes in ``setup``).
        num_frames, height, width: model input geometry; frames are resized with PIL.
            None (default): the model's, resolved in ``setup`` (its ``training_frames`` and
            ``image_size`` hyperparameters, from the checkpoint under ``test --ckpt_path``).
        frames_per_movie: frames in every movie folder (IntPhys: 100).
        frame_stride, first_frame: sample every ``frame_stride``-th frame from ``first_frame``;
            by default ``num_frames`` frames spread evenly over the whole movie.
        divergence_level, divergence_fraction: a frame differs when more than this fraction of
            its pixels differ by more than this many grey levels (tolerates renderer noise).
        eval_split: split of the validation and test probes (needs labels: ``dev``).
        predict_split: split whose movies ``predict_dataloader`` serves.
        lenient: skip malformed scenes and movies instead of raising; ``skipped`` counts them.
        cache_dir: if set, decoded records are written there once (store shards) and reused.
        seed: seed of the training order.
    """

    without_masks = "IntPhys"

    concept_names, variant_names = CONCEPT_NAMES, VARIANT_NAMES

    def __init__(
        self,
        root: str = "data/intphys",
        batch_size: int = 10,
        probe_batch_size: int = 32,
        num_workers: int = 0,
        num_frames: int | None = None,
        height: int | None = None,
        width: int | None = None,
        frames_per_movie: int = 100,
        frame_stride: int | None = None,
        first_frame: int = 0,
        divergence_level: int = 10,
        divergence_fraction: float = 0.001,
        eval_split: str = "dev",
        predict_split: str = "test",
        lenient: bool = False,
        cache_dir: str | None = None,
        seed: int = 0,
    ):
        super().__init__()
        check_at_least(
            {
                "batch_size": (batch_size, 1),
                "probe_batch_size": (probe_batch_size, 1),
                "height": (height, 1),
                "width": (width, 1),
                "num_workers": (num_workers, 0),
                "num_frames": (num_frames, 1),
                "frames_per_movie": (frames_per_movie, 1),
                "frame_stride": (frame_stride, 1),
                "first_frame": (first_frame, 0),
                "divergence_level": (divergence_level, 0),
            }
        )
        check_fraction("divergence_fraction", divergence_fraction)
        for name, split in [("eval_split", eval_split), ("predict_split", predict_split)]:
            if split not in ("dev", "test"):
                raise ValueError(f"{name} must be 'dev' or 'test', got {split!r}")
        if eval_split == "test":
            raise ValueError("eval_split='test' has no labels to pair movies by; use 'dev'")
        self.save_hyperparameters()
        self.source_frames = frames_per_movie
        self._resolve_video(required=False)
        self._train: Dataset[TensorDict] | None = None
        self._movies: dict[str, list[Movie]] = {}

    # --- building --------------------------------------------------------------------------------
    def setup(self, stage: str | None = None) -> None:
        self._resolve_video()
        h = self.hparams
        if stage in ("fit", None):
            self._setup_train()
        if stage in ("fit", "validate", "test", None):
            self.probes(h["eval_split"])
        if stage == "predict":
            self.movies(h["predict_split"])

    def _settings(self, what: str) -> dict[str, Any]:
        h = self.hparams
        return {
            "what": what,
            "video": self.video.__dict__,
            "frames_per_movie": h["frames_per_movie"],
            "lenient": h["lenient"],
            "records": RECORD_VERSION,
        }

    def _frames(self, movie: Path) -> list[Path]:
        """A movie's frame files, the sources a cache fingerprints: a frame rewritten in place
        changes its file's size or mtime, never its folder's."""
        return [frame_file(movie, i) for i in range(1, self.hparams["frames_per_movie"] + 1)]

    def _cache_folder(self, what: str, sources: list[Path]) -> Path | None:
        if self.hparams["cache_dir"] is None:
            return None
        key = fingerprint(self._settings(what), sources)
        return Path(self.hparams["cache_dir"]) / "intphys" / what / key

    def probes(self, split: str = "dev") -> Dataset[TensorDict]:
        """The probe pairs of a labelled split (decoded once; from the cache when there is one)."""
        if split in self._probes:
            return self._probes[split]
        h = self.hparams
        skips = self._skips[split] = SkipLog()
        quadruplets = scan_quadruplets(
            h["root"], split, h["frames_per_movie"], True, h["lenient"], skips
        )
        sources = [
            p
            for q in quadruplets
            for m in q.movies
            for p in (*self._frames(m.path), m.path / "status.json")
        ]
        decoder = QuadrupletDataset(quadruplets, self.video, h["lenient"], skips)
        return self._read_probes(split, decoder, self._cache_folder(split, sources), "scene")

    def quadruplets(self, split: str = "dev") -> dict[int, dict[str, Any]]:
        """quadruplet_index -> {block, scene, condition, ambiguous_pairing, pairs: [{possible,
        impossible, divergence_frame, divergence_source_frame}]} (pair j has seed q and variant
        j: ``standard``, ``counterbalanced``)."""
        self.probes(split)
        return self._tables[split]

    def _setup_train(self) -> None:
        if self._train is not None:
            return
        h = self.hparams
        skips = self._skips["train"] = SkipLog()
        movies = scan_train(h["root"], h["frames_per_movie"], h["lenient"], skips)
        folder = self._cache_folder("train", [p for m in movies for p in self._frames(m)])
        if folder is None:
            self._train = TrainClipDataset(movies, self.video, h["lenient"], skips, substitute=True)
            return
        cached = open_cache(folder, {"skipped": dict})
        if cached is None:
            converting = TrainClipDataset(movies, self.video, h["lenient"], skips, substitute=False)
            meta: dict[str, Any] = {}
            records = self._convert(converting, meta, skips)
            cached = write_cache(folder, records, self.clip_spec(), meta)
        self._skips["train"] = SkipLog()
        self._cached_skips["train"] = cached.meta.get("skipped", {})
        self._train = cached

    def _convert(
        self, dataset: TrainClipDataset, meta: dict[str, Any], skips: SkipLog
    ) -> Iterator[TensorDict]:
        loader = worker_loader(dataset, self.hparams["num_workers"])
        for record in tqdm(loader, desc="caching IntPhys train", unit="movie", leave=False):
            if record is not None:
                yield record
        meta["skipped"] = skips.counts()

    def movies(self, split: str = "test") -> list[Movie]:
        """Every movie of ``split`` in answer.txt order (labels are None for ``test``)."""
        if split not in self._movies:
            h = self.hparams
            quadruplets = scan_quadruplets(h["root"], split, h["frames_per_movie"], split == "dev")
            self._movies[split] = sorted(
                (m for q in quadruplets for m in q.movies), key=lambda m: m.name
            )
        return self._movies[split]

    def probe_cases(self, split: str = "val") -> list[tuple[str, str]]:
        """The (concept, variant) names present among the evaluation probes: each block's two
        quadruplet halves."""
        table = self.quadruplets(self.hparams["eval_split"])
        blocks = sorted({CONCEPT_NAMES[BLOCKS.index(e["block"])] for e in table.values()})
        return [(block, variant) for block in blocks for variant in VARIANT_NAMES]

    # --- loaders ---------------------------------------------------------------------------------
    def train_dataloader(self) -> DataLoader[TensorDict]:
        self._setup_train()
        assert self._train is not None  # built by _setup_train
        generator = torch.Generator().manual_seed(self.hparams["seed"])
        return self._loader(
            self._train,
            self.hparams["batch_size"],
            shuffle=True,
            drop_last=True,
            generator=generator,
        )

    def val_dataloader(self) -> DataLoader[TensorDict]:
        return self._probe_loader(self.probes(self.hparams["eval_split"]))

    def test_dataloader(self) -> DataLoader[TensorDict]:
        return self.val_dataloader()

    def predict_dataloader(self) -> DataLoader[TensorDict]:
        return self._probe_loader(
            MovieDataset(self.movies(self.hparams["predict_split"]), self.video)
        )

    # --- evaluation ------------------------------------------------------------------------------
    def external_pairs(self) -> ExternalPairs:
        """The evaluated split's quadruplets (``quadruplets``) and skipped counts, for IntPhys'
        metrics (``voe_lightning.benchmarks.evaluation``)."""
        split = self.hparams["eval_split"]
        return ExternalPairs(
            "IntPhys", self.concept_names, split, self.quadruplets(split), self.skipped
        )

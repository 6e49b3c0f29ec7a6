"""IntPhys 2 (Bordes et al. 2025) as a LightningDataModule: the labelled Possible/Impossible
pairs of a split for ``validate``/``test`` (with the benchmark's metrics and videos.csv in the
report), and single videos for ``predict`` (the leaderboard's jsonl, see
``voe_lightning.callbacks.prediction_writer.IntPhys2LeaderboardWriter``); the reading is
``reader``, beside it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tensordict import TensorDict
from torch.utils.data import DataLoader, Dataset

from voe_lightning.benchmarks.cache import fingerprint
from voe_lightning.benchmarks.datamodule import ExternalDataModule
from voe_lightning.benchmarks.external_pairs import ExternalPairs
from voe_lightning.benchmarks.intphys2.reader import (
    PRINCIPLES,
    RECORD_VERSION,
    SPLITS,
    VARIANT_NAMES,
    SceneDataset,
    Video,
    VideoDataset,
    pair_videos,
    read_metadata,
)
from voe_lightning.benchmarks.mp4 import ClipSampling
from voe_lightning.benchmarks.reader import SkipLog
from voe_lightning.datamodule_arguments import check_at_least, check_fraction


class IntPhys2DataModule(ExternalDataModule):
    """IntPhys 2 for ``validate``/``test`` (Possible/Impossible pairs of ``eval_split``, default
    Main) and ``predict`` (single videos of ``predict_split``, default HeldOut). No ``fit``:
    IntPhys 2 has no training videos.

    Args:
        root: folder holding ``Debug/``, ``Main/`` and ``HeldOut/`` (each ``metadata.csv`` and
            ``Videos/<name>.mp4``).
        probe_batch_size: probe pairs (or videos) per batch.
        num_workers: DataLoader worker processes (also used to decode the pairs in ``setup``).
        num_frames, height, width: model input geometry; frames are resized with PIL.
            None (default): the model's (its ``training_frames`` and ``image_size``
            hyperparameters); a model without them (``CueScorer``) needs them given.
        frame_stride: take every ``frame_stride``-th frame from ``first_frame`` (the V-JEPA
            evaluation's frame step); None (default): ``num_frames`` spread evenly over each
            video, whatever its length.
        first_frame: first source frame sampled.
        divergence_level, divergence_fraction: a frame differs when more than this fraction of
            its pixels differ by more than this many grey levels (tolerates mp4 noise).
        eval_split: split of the validation and test pairs (labelled: Debug or Main).
        predict_split: split whose videos ``predict_dataloader`` serves.
        lenient: skip bad rows, missing or undecodable videos and malformed scene groups
            instead of raising; ``skipped`` counts them per reason.
        cache_dir: if set, decoded pairs are written there once (store shards) and reused.
    """

    without_masks = "IntPhys 2"

    concept_names, variant_names = PRINCIPLES, VARIANT_NAMES
    #: Videos differ in length, so frames are picked per video (``ClipSampling``); this bound
    #: only lets the shared geometry (``ExternalDataModule.video``) resolve.
    source_frames = 1 << 30

    def __init__(
        self,
        root: str = "data/intphys2",
        probe_batch_size: int = 8,
        num_workers: int = 0,
        num_frames: int | None = None,
        height: int | None = None,
        width: int | None = None,
        frame_stride: int | None = None,
        first_frame: int = 0,
        divergence_level: int = 10,
        divergence_fraction: float = 0.001,
        eval_split: str = "Main",
        predict_split: str = "HeldOut",
        lenient: bool = False,
        cache_dir: str | None = None,
    ):
        super().__init__()
        check_at_least(
            {
                "probe_batch_size": (probe_batch_size, 1),
                "num_workers": (num_workers, 0),
                "num_frames": (num_frames, 1),
                "height": (height, 1),
                "width": (width, 1),
                "frame_stride": (frame_stride, 1),
                "first_frame": (first_frame, 0),
                "divergence_level": (divergence_level, 0),
            }
        )
        check_fraction("divergence_fraction", divergence_fraction)
        for name, split in [("eval_split", eval_split), ("predict_split", predict_split)]:
            if split not in SPLITS:
                raise ValueError(f"{name} must be one of {', '.join(SPLITS)}, got {split!r}")
        if eval_split == "HeldOut":
            raise ValueError(
                "eval_split='HeldOut' has no labels to pair videos by; use 'Main' or 'Debug'"
            )
        self.save_hyperparameters()
        self._resolve_video(required=False)
        self._videos: dict[str, list[Video]] = {}

    @property
    def sampling(self) -> ClipSampling:
        return ClipSampling(self.video, self.hparams["frame_stride"], self.hparams["first_frame"])

    # --- building --------------------------------------------------------------------------------
    def setup(self, stage: str | None = None) -> None:
        self._resolve_video()
        if stage in ("fit", "validate", "test", None):
            self.probes(self.hparams["eval_split"])
        if stage == "predict":
            self.videos(self.hparams["predict_split"])

    def probes(self, split: str = "Main") -> Dataset[TensorDict]:
        """The probe pairs of a labelled split (decoded once; from the cache when there is one)."""
        if split in self._probes:
            return self._probes[split]
        h = self.hparams
        skips = self._skips[split] = SkipLog()
        pairs = pair_videos(
            read_metadata(h["root"], split, True, h["lenient"], skips), h["lenient"], skips
        )
        folder = None
        if h["cache_dir"] is not None:
            settings = {
                "what": split,
                "video": self.video.__dict__,
                "frame_stride": h["frame_stride"],
                "first_frame": h["first_frame"],
                "lenient": h["lenient"],
                "records": RECORD_VERSION,
            }
            sources = [Path(h["root"]) / split / "metadata.csv"] + [
                v.path for pair in pairs for v in (pair.possible, pair.impossible)
            ]
            folder = Path(h["cache_dir"]) / "intphys2" / split / fingerprint(settings, sources)
        return self._read_probes(
            split, SceneDataset(pairs, self.sampling, h["lenient"], skips), folder, "scene"
        )

    def pairs(self, split: str = "Main") -> dict[tuple[int, str], dict[str, Any]]:
        """(seed: the scene's index, variant: the pair's half) -> {scene, prefix, condition,
        principle, difficulty, camera, possible, impossible (video names), possible_row,
        impossible_row, divergence_frame}."""
        self.probes(split)
        return {
            (seed, variant): entry
            for seed, scene in self._tables[split].items()
            for variant, entry in scene.items()
        }

    def videos(self, split: str = "HeldOut") -> list[Video]:
        """Every video of ``split`` in metadata order (labels read where the split has them)."""
        if split not in self._videos:
            self._videos[split] = read_metadata(self.hparams["root"], split, split != "HeldOut")
        return self._videos[split]

    def probe_cases(self, split: str = "val") -> list[tuple[str, str]]:
        """The (principle, half) names present among the evaluation pairs."""
        table = self.pairs(self.hparams["eval_split"])
        return sorted(
            {(e["principle"], variant) for (_, variant), e in table.items()},
            key=lambda case: (case[0], VARIANT_NAMES.index(case[1])),
        )

    # --- loaders ---------------------------------------------------------------------------------
    def val_dataloader(self) -> DataLoader[TensorDict]:
        return self._probe_loader(self.probes(self.hparams["eval_split"]))

    def test_dataloader(self) -> DataLoader[TensorDict]:
        return self.val_dataloader()

    def predict_dataloader(self) -> DataLoader[TensorDict]:
        return self._probe_loader(
            VideoDataset(self.videos(self.hparams["predict_split"]), self.sampling)
        )

    # --- evaluation ------------------------------------------------------------------------------
    def external_pairs(self) -> ExternalPairs:
        """The evaluated split's pairs (``pairs``) and skipped counts, for IntPhys 2's metrics
        and videos.csv (``voe_lightning.benchmarks.evaluation``)."""
        split = self.hparams["eval_split"]
        return ExternalPairs(
            "IntPhys 2", self.concept_names, split, self.pairs(split), self.skipped
        )

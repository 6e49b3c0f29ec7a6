"""What the DataModules of the external benchmarks (IntPhys, IntPhys 2, Physical Concepts)
share: record specs over the benchmark's own vocabularies, skipped-input counts, loader settings
and the model input geometry. Each benchmark's DataModule is ``<benchmark>.datamodule`` beside
its ``<benchmark>.reader``; their metrics, ``voe_lightning.benchmarks.evaluation`` (from each
DataModule's ``external_pairs``)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from tensordict import TensorDict
from torch.utils.data import DataLoader, Dataset
from torchrl.data import Composite
from tqdm import tqdm

from voe_lightning import specs
from voe_lightning.benchmarks.cache import open_cache, write_cache
from voe_lightning.benchmarks.reader import (
    FrameSampling,
    RecordList,
    SkipLog,
    benchmark_spec,
    frame_indices,
    merge_counts,
    worker_loader,
)
from voe_lightning.data.store import probe_sampler, record_loader
from voe_lightning.probe_datamodule import ProbeDataModule

#: What decodes a benchmark's probes: item k, the records of its k-th scene or quadruplet and
#: their pairing table entry (None: skipped under ``lenient``).
ProbeDecoder = Dataset[tuple[list[TensorDict], dict[str, Any] | None]]


class ExternalDataModule(ProbeDataModule):
    """What the external benchmarks' DataModules share: their record specs (over their own
    concept and variant vocabularies; a benchmark has no object states), the counts of skipped
    input, the loader settings, and the model input geometry (``video``): num_frames, height and width as given, or, left None, the
    model's (its ``training_frames`` and ``image_size`` hyperparameters), resolved in ``setup``.
    Subclasses set ``concept_names``/``variant_names`` and ``source_frames`` (frames of every
    source video), save hyperparameters num_frames, height, width, frame_stride, first_frame,
    divergence_level, divergence_fraction, num_workers, and call ``_resolve_video(False)`` at
    the end of ``__init__`` (given values are checked at once) and ``_resolve_video()`` at the
    start of ``setup``."""

    source_frames: int

    def __init__(self) -> None:
        super().__init__()
        self._skips: dict[str, SkipLog] = {}
        self._cached_skips: dict[str, dict[str, int]] = {}
        self._video: FrameSampling | None = None
        self._probes: dict[str, Dataset[TensorDict]] = {}
        self._tables: dict[str, dict[int, dict[str, Any]]] = {}

    @property
    def video(self) -> FrameSampling:
        """Which source frames become the model's input, at what size."""
        if self._video is None:
            raise RuntimeError(
                f"{type(self).__name__}: num_frames, height or width is left to the model; call "
                "setup() under a trainer with the model, or give them"
            )
        return self._video

    def _resolve_video(self, required: bool = True) -> None:
        """Build ``video`` from num_frames, height and width, taking those left None from the
        trainer's model; ``required`` (in ``setup``) refuses what neither gives, naming it."""
        h = self.hparams
        given = {"num_frames": h["num_frames"], "height": h["height"], "width": h["width"]}
        model = getattr(self.trainer, "lightning_module", None)
        model_hparams = getattr(model, "hparams", {})
        height, width = model_hparams.get("image_size") or (None, None)
        from_model = {
            "num_frames": model_hparams.get("training_frames"),
            "height": height,
            "width": width,
        }
        geometry: dict[str, Any] = {
            name: from_model[name] if value is None else value for name, value in given.items()
        }
        unresolved = [name for name, value in geometry.items() if value is None]
        if unresolved and required:
            wanted = {
                "num_frames": "training_frames",
                "height": "image_size",
                "width": "image_size",
            }
            source = (
                "there is no model"
                if model is None
                else (
                    "the model's hyperparameters have no "
                    + " or ".join(dict.fromkeys(wanted[name] for name in unresolved))
                )
            )
            raise ValueError(
                f"{type(self).__name__}: {', '.join(unresolved)} not given and {source} to "
                "take them from; give " + ", ".join(f"--data.init_args.{n}" for n in unresolved)
            )
        if not unresolved:
            indices = frame_indices(
                self.source_frames, geometry["num_frames"], h["frame_stride"], h["first_frame"]
            )
            self._video = FrameSampling(
                tuple(indices.tolist()),
                geometry["height"],
                geometry["width"],
                h["divergence_level"],
                h["divergence_fraction"],
            )

    def probe_spec(self) -> Composite:
        v = self.video
        base = specs.probe_spec(len(v.indices), v.height, v.width, objects=False)
        return benchmark_spec(base, len(self.concept_names), len(self.variant_names))

    def clip_spec(self) -> Composite:
        v = self.video
        return benchmark_spec(
            specs.clip_spec(len(v.indices), v.height, v.width, objects=False),
            len(self.concept_names),
        )

    @property
    def skipped(self) -> dict[str, int]:
        """Items left out under ``lenient=True``, per reason (this run's and cached builds')."""
        logs = (log.counts() for log in self._skips.values())
        return merge_counts(*logs, *self._cached_skips.values())

    def _loader(
        self, dataset: Dataset[TensorDict], batch_size: int, **kwargs: Any
    ) -> DataLoader[TensorDict]:
        return record_loader(dataset, batch_size, self.hparams["num_workers"], **kwargs)

    def _probe_loader(self, dataset: Dataset[TensorDict]) -> DataLoader[TensorDict]:
        """Probe pairs or single videos in order, each on one DDP rank."""
        return self._loader(
            dataset, self.hparams["probe_batch_size"], sampler=probe_sampler(dataset)
        )

    def _read_probes(
        self, split: str, decoder: ProbeDecoder, folder: Path | None, unit: str
    ) -> Dataset[TensorDict]:
        """The probe records of ``split`` from the cache at ``folder`` when it is intact, else
        decoded by ``decoder`` (items: (records, table entry or None)) in worker processes and
        written there (``folder`` None: kept in memory). Fills ``_probes[split]`` and
        ``_tables[split]`` (a record's seed -> its item's entry) and the skipped counts."""
        cached = open_cache(folder, {"table": dict, "skipped": dict}) if folder else None
        if cached is not None:  # its counts already include this scan's skips
            self._skips[split] = SkipLog()
            self._cached_skips[split] = cached.meta.get("skipped", {})
            self._tables[split] = {int(k): v for k, v in cached.meta["table"].items()}
            self._probes[split] = cached
            return cached
        meta: dict[str, Any] = {"table": {}}
        records = self._decode(decoder, meta, self._skips[split], split, unit)
        self._probes[split] = (
            RecordList(list(records))
            if folder is None
            else write_cache(folder, records, self.probe_spec(), meta)
        )
        self._tables[split] = meta["table"]
        return self._probes[split]

    def _decode(
        self, decoder: ProbeDecoder, meta: dict[str, Any], skips: SkipLog, what: str, unit: str
    ) -> Iterator[TensorDict]:
        """The probe records, decoded by worker processes; fills ``meta`` (table, skipped
        counts) as it goes, complete once exhausted."""
        loader = worker_loader(decoder, self.hparams["num_workers"])
        for records, entry in tqdm(
            loader, desc=f"decoding {type(self).__name__} {what}", unit=unit, leave=False
        ):
            if entry is not None:
                meta["table"][int(records[0]["seed"])] = entry
            yield from records
        meta["skipped"] = skips.counts()

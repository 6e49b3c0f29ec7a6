"""The ``generate`` command (``python -m voe_lightning generate``): its flags, a preset's video
settings beneath those given (``video_presets``), the store's ``generate_dataset``, a line saying
what it did, and contact sheets of the store it wrote (``contact_sheet``)."""

from __future__ import annotations

from pathlib import Path
from typing import get_args

from voe_lightning import specs
from voe_lightning.data.store.generation import GenerationSummary, generate_dataset
from voe_lightning.data.store.plan import (
    DEFAULT_GENERALIZATION_PAIRS,
    DEFAULT_SHARD_SIZE,
    DEFAULT_TEST_PAIRS,
    DEFAULT_VAL_PAIRS,
)
from voe_lightning.data.video_presets import PresetName, check_preset


def generate(
    root: Path,
    concepts: list[specs.Concept] = list(get_args(specs.Concept)),  # noqa: B006, B008 (the CLI reads it; never mutated)
    train_examples: int | None = None,
    train_controls: int | None = None,
    val_pairs: int = DEFAULT_VAL_PAIRS,
    test_pairs: int = DEFAULT_TEST_PAIRS,
    generalization_pairs: int = DEFAULT_GENERALIZATION_PAIRS,
    shard_size: int = DEFAULT_SHARD_SIZE,
    workers: int | None = None,
    shard_index: int = 0,
    num_shards: int = 1,
    num_frames: int | None = None,
    height: int | None = None,
    width: int | None = None,
    fps: float | None = None,
    preset: PresetName | None = None,
    overwrite: bool = False,
    contact_sheets: bool = False,
    progress: bool = True,
    seed_offset: int = 0,
) -> GenerationSummary:
    """Render the concepts' training clips and probe pairs into a sharded store.

    Resumable: shards that exist and verify are kept, missing or corrupt ones are rendered
    again. generate_dataset, printing what it did.

    Args:
        root: dataset folder.
        concepts: concepts to generate.
        train_examples: training examples per concept (default 10,000; none with a
            seed_offset).
        train_controls: training controls per concept, split evenly over its control kinds
            (default: as many as examples).
        val_pairs: validation probe pairs per concept and variant.
        test_pairs: test probe pairs per concept and variant.
        generalization_pairs: generalization probe pairs per concept and variant.
        shard_size: records per shard.
        workers: rendering processes (default: all cores).
        shard_index: this job's slice of the shards (cluster job arrays).
        num_shards: number of slices (the job array's size).
        num_frames: frames per video (default 15, or the preset's).
        height: frame height (default 64, or the preset's).
        width: frame width (default 64, or the preset's).
        fps: frames per second; a clip lasts num_frames / fps s, 2.5 to 4.5 (default, or
            the preset's: num_frames over the paper's 3 s, 5 at 15 frames).
        preset: the frames, fps and size a harness windows (flags given beside it win):
            paper (15 frames of 64 x 64 at 5 fps), intphys (100 of 288 x 288 at 33.3),
            intphys2_vjepa (160 of 224 x 224 at 53.3), intphys2_vjepa2 (480 of 256 x 256 at
            160); all 3 s (docs/benchmarks.md).
        overwrite: delete data generated with other settings instead of refusing.
        contact_sheets: write ROOT/contact_sheets/<concept>.png from the store at the end.
        progress: show a progress bar.
        seed_offset: shift the probe splits' seeds by this much (0 to 999,999,999 less the
            pairs per variant, and no less than ROOT's pairs per variant, whose seeds it would
            draw again) for a fresh test set no one has seen, written to its own store,
            ROOT/seed_offset_<N> (probes only; printed).
    """
    num_frames, height, width, fps = _with_preset(preset, num_frames, height, width, fps)
    summary = generate_dataset(
        root, concepts, train_examples, train_controls, val_pairs=val_pairs,
        test_pairs=test_pairs, generalization_pairs=generalization_pairs,
        shard_size=shard_size, workers=workers, num_frames=num_frames, height=height, width=width,
        shard_index=shard_index, num_shards=num_shards, overwrite=overwrite, progress=progress,
        seed_offset=seed_offset, fps=fps,
    )  # fmt: skip
    print(
        f"{summary.root}: {summary.shards_generated} shards generated "
        f"({summary.records_generated} records, {summary.bytes_written / 1e6:.1f} MB), "
        f"{summary.shards_skipped} already complete, {summary.seconds:.1f} s"
    )
    if contact_sheets:
        from voe_lightning.data.contact_sheet import write_store_sheet

        for concept in dict.fromkeys(concepts):
            path = summary.root / "contact_sheets" / f"{concept}.png"
            write_store_sheet(summary.root, concept, path)
            print(f"wrote {path}")
    return summary


def _with_preset(
    preset: str | None,
    num_frames: int | None,
    height: int | None,
    width: int | None,
    fps: float | None,
) -> tuple[int, int, int, float | None]:
    """``generate``'s video flags: each one given, else ``preset``'s value (a bad name is
    refused, naming the valid ones), else the default (None for ``fps``: 3 s clips)."""
    if preset is None:
        return (
            specs.NUM_FRAMES if num_frames is None else num_frames,
            specs.HEIGHT if height is None else height,
            specs.WIDTH if width is None else width,
            fps,
        )
    chosen = check_preset(preset)
    return (
        chosen.num_frames if num_frames is None else num_frames,
        chosen.height if height is None else height,
        chosen.width if width is None else width,
        chosen.fps if fps is None else fps,
    )

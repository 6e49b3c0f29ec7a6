"""A tiny DeepMind Physical Concepts dataset in the released layout (GZIP TFRecord shards of
freeform clips and probe quadruplets, written with the tfrecord package) and the DataModule that
reads it: the Physical Concepts reader tests' fixture, which other tests train and score on."""

import gzip
import struct
import tempfile
from pathlib import Path

import numpy as np
from tfrecord.writer import TFRecordWriter

from voe_lightning.benchmarks.physical_concepts.datamodule import PhysicalConceptsDataModule

T, H, W = 15, 64, 64
#: num_frames=5 of 15 samples frames [0, 4, 7, 10, 14].
SAMPLED = [0, 4, 7, 10, 14]
CONCEPTS = ["continuity", "solidity"]


def world_video(seed: int, world: str, switch: int | None = None, then: str | None = None):
    """[15, 64, 64, 3] frames and [15, 64, 64] masks of a world's object; from ``switch`` on,
    the other world's."""
    background = np.random.default_rng(seed).integers(0, 100, (H, W, 3), dtype=np.uint8)
    frames, masks = [], []
    for t in range(T):
        current = then if switch is not None and t >= switch else world
        frame, mask = background.copy(), np.zeros((H, W), np.uint8)
        frame[t, :, 1] = 250
        if current == "A":
            frame[10:20, 10:20], mask[10:20, 10:20] = (255, 0, 0), 1
        else:
            frame[40:55, 40:55], mask[40:55, 40:55] = (0, 0, 255), 2
        frames.append(frame)
        masks.append(mask)
    return np.stack(frames), np.stack(masks)


def probe_example(seed: int, switch_ab: int, switch_ba: int):
    """possible = [A, B]; impossible = [B->A, A->B] (partners swapped, so pairing must be
    recovered); camera of possible video k at frame t = 100 k + t."""
    pa, pb = world_video(seed, "A"), world_video(seed, "B")
    iba, iab = world_video(seed, "B", switch_ba, "A"), world_video(seed, "A", switch_ab, "B")
    camera = np.stack(
        [np.full((T, 6), 100 * k, np.float32) + np.arange(T)[:, None] for k in range(2)]
    )
    return {
        "possible_image": (np.stack([pa[0], pb[0]]).tobytes(), "byte"),
        "possible_mask": (np.stack([pa[1], pb[1]]).tobytes(), "byte"),
        "possible_camera_pose": (camera.ravel().tolist(), "float"),
        "impossible_image": (np.stack([iba[0], iab[0]]).tobytes(), "byte"),
        "impossible_mask": (np.stack([iba[1], iab[1]]).tobytes(), "byte"),
        "impossible_camera_pose": ((camera + 0.5).ravel().tolist(), "float"),
    }


def freeform_example(seed: int):
    frames, masks = world_video(seed, "A")
    camera = np.full((T, 6), seed, np.float32) + np.arange(T)[:, None]
    return {
        "image": (frames.tobytes(), "byte"),
        "mask": (masks.tobytes(), "byte"),
        "camera_pose": (camera.ravel().tolist(), "float"),
    }


def write_shard(
    path: Path, examples, corrupt_record: int | None = None, truncate: int | None = None
):
    """A GZIP-compressed TFRecord file written with the tfrecord package's writer."""
    with tempfile.TemporaryDirectory() as scratch:
        plain = Path(scratch) / "plain.tfrecord"
        writer = TFRecordWriter(str(plain))
        for example in examples:
            writer.write(example)
        writer.close()
        data = bytearray(plain.read_bytes())
    if corrupt_record is not None:  # flip a payload byte of that record
        offset = 0
        for _ in range(corrupt_record):
            offset += 16 + struct.unpack("<Q", data[offset : offset + 8])[0]
        data[offset + 12 + 20] ^= 0xFF
    compressed = gzip.compress(bytes(data))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(compressed[:truncate] if truncate else compressed)


#: (A->B switch, B->A switch) per probe record, per concept shard.
SWITCHES = [(6, 9), (3, 12)]


def make_dataset(root: Path) -> Path:
    for shard in range(2):
        write_shard(
            root / "freeform" / "train" / f"data.tfrecord-{shard:05d}-of-00002",
            [freeform_example(10 * shard + k) for k in range(3)],
        )
    write_shard(root / "freeform" / "test" / "data.tfrecord-00000-of-00001", [freeform_example(99)])
    for concept in CONCEPTS:
        for shard in range(2):
            write_shard(
                root / "probes" / concept / f"data.tfrecord-{shard:05d}-of-00002",
                [probe_example(20 * shard + k, *SWITCHES[k]) for k in range(2)],
            )
    return root


def datamodule(root, **options):
    settings = dict(
        root=str(root),
        concepts=CONCEPTS,
        num_frames=5,
        height=32,
        width=32,
        batch_size=2,
        probe_batch_size=4,
        val_quadruplets_per_concept=1,
        shuffle_buffer=4,
    )
    settings.update(options)
    return PhysicalConceptsDataModule(**settings)

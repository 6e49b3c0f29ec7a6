"""A tiny IntPhys dataset in the released layout (``dev``/``test`` scenes of four movies,
``train`` movies) and the DataModule that reads it: the IntPhys reader tests' fixture, which
other tests run the CLI and the scorers on."""

import json

import numpy as np
from PIL import Image

from voe_lightning.benchmarks.intphys.datamodule import IntPhysDataModule

FRAMES, SIZE = 20, 32
#: num_frames=5 of 20 samples source frames [0, 5, 10, 14, 19].
SAMPLED = [0, 5, 10, 14, 19]
#: scene -> (A->B switch frame, B->A switch frame, folder of [possible A, possible B,
#: impossible A->B, impossible B->A]); switch frames are source frames.
SCENES = {
    "O1/0001_O1_test_visible_static_nobj1": (7, 12, ["1", "4", "3", "2"]),
    "O1/0002_O1_test_occluded_dynamic_1_nobj2": (3, 16, ["2", "3", "1", "4"]),
    "O2/0003": (11, 5, ["4", "1", "2", "3"]),
}


def world_frame(scene_seed: int, world: str, t: int) -> np.ndarray:
    """A background shared by the scene, a time marker, and the world's object."""
    image = np.random.default_rng(scene_seed).integers(0, 120, (SIZE, SIZE, 3), dtype=np.uint8)
    image[t % SIZE, :, 1] = 250
    if world == "A":
        image[4:12, 4:12] = (255, 0, 0)
    else:
        image[18:28, 18:28] = (0, 0, 255)
    return image


def movie_worlds(kind: str, switch: int) -> list[str]:
    start, end = {"pA": "AA", "pB": "BB", "iAB": "AB", "iBA": "BA"}[kind]
    return [start if t < switch else end for t in range(FRAMES)]


def write_movie(folder, frames, label=None):
    (folder / "scene").mkdir(parents=True)
    for number, frame in enumerate(frames, 1):
        Image.fromarray(frame).save(folder / "scene" / f"scene_{number:03d}.png")
    if label is not None:
        header = {"block_name": "O1", "block_type": "test", "is_possible": label}
        (folder / "status.json").write_text(json.dumps({"header": header, "frames": []}))


def make_intphys(root, split="dev", labelled=True):
    for seed, (scene, (switch_ab, switch_ba, folders)) in enumerate(SCENES.items()):
        kinds = {
            "pA": (folders[0], True, switch_ab),
            "pB": (folders[1], True, switch_ab),
            "iAB": (folders[2], False, switch_ab),
            "iBA": (folders[3], False, switch_ba),
        }
        for kind, (folder, possible, switch) in kinds.items():
            frames = [world_frame(seed, w, t) for t, w in enumerate(movie_worlds(kind, switch))]
            write_movie(root / split / scene / folder, frames, possible if labelled else None)
    return root


def make_train(root, movies=3):
    for index in range(movies):
        frames = [world_frame(100 + index, "A", t) for t in range(FRAMES)]
        write_movie(root / "train" / f"{index:05d}", frames)


def datamodule(root, **options):
    settings = dict(
        root=str(root),
        num_frames=5,
        height=16,
        width=16,
        frames_per_movie=FRAMES,
        batch_size=2,
        probe_batch_size=4,
    )
    settings.update(options)
    return IntPhysDataModule(**settings)

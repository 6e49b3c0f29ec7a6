"""A tiny IntPhys 2 dataset in the released layout: lossless mp4s of every principle and both
prefixes, Main's rows shuffled, Debug's ``filename`` column, Held-Out without labels (the IntPhys
2 reader tests' fixture, which other tests run the CLI on)."""

import csv
import random
from pathlib import Path

import av
import numpy as np

from voe_lightning.benchmarks.intphys2.reader import METADATA_COLUMNS

FRAMES, SIZE = 8, 16
COLUMNS = list(METADATA_COLUMNS)
#: scene -> (condition, principle, difficulty, camera); one scene per principle.
SCENES = {
    "3": ("permanence", "Permanence", "Easy", "Static"),
    "10": ("immutability_texture", "Immutability", "Medium", "Static"),
    "10_1": ("continuity_swap", "Continuity", "Hard", "Moving"),
    "25": ("solidity", "Solidity", "Hard", "Moving"),
}
#: prefix -> (the possible video's object, the impossible one's object after the switch,
#: switch source frame, first sampled frame that differs)
PREFIXES = {"1": ("A", "B", 4, 2), "2": ("B", "A", 6, 3)}


def write_mp4(path, frames):
    """A lossless RGB H.264 mp4 (PyAV), so decoded pixels equal the ones written."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264rgb", rate=10)
        stream.width, stream.height, stream.pix_fmt = SIZE, SIZE, "rgb24"
        stream.options = {"qp": "0"}
        for frame in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")))
        container.mux(stream.encode())


def frame(seed, world, t):
    image = np.random.default_rng(seed).integers(0, 100, (SIZE, SIZE, 3), dtype=np.uint8)
    image[t % SIZE, :, 1] = 250  # a time marker
    if world == "A":
        image[2:7, 2:7] = (255, 0, 0)
    else:
        image[9:14, 9:14] = (0, 0, 255)
    return image


def scene_rows(split_dir, number, scene, frames=FRAMES, id_column="file_name"):
    condition, _, difficulty, camera = SCENES[scene]
    rows = []
    for prefix, (world, other, switch, _) in PREFIXES.items():
        for kind in ("Possible", "Impossible"):
            name = f"s{scene}_{prefix}_{kind.lower()}"
            worlds = [world if kind == "Possible" or t < switch else other for t in range(frames)]
            write_mp4(
                split_dir / "Videos" / f"{name}.mp4",
                [frame(number, w, t) for t, w in enumerate(worlds)],
            )
            rows.append(
                {
                    "SceneIndex": scene,
                    "name": name,
                    id_column: f"{name}.mp4",
                    "game_name": "g",
                    "condition": condition,
                    "env": "e",
                    "type": f"{prefix}_{kind}",
                    "occluder": "o",
                    "Difficulty": difficulty,
                    "Camera": camera,
                }
            )
    return rows


def write_metadata(split_dir, rows, columns=COLUMNS):
    with open(split_dir / "metadata.csv", "w", newline="") as stream:
        writer = csv.DictWriter(stream, columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def make_root(root: Path) -> Path:
    """A tiny IntPhys 2 layout under ``root``: Main (shuffled rows), Debug and HeldOut."""
    rows = [
        row
        for number, scene in enumerate(SCENES)
        for row in scene_rows(root / "Main", number, scene)
    ]
    random.Random(0).shuffle(rows)
    write_metadata(root / "Main", rows)
    debug = scene_rows(root / "Debug", 7, "3", frames=12, id_column="filename")
    for row in debug:
        row["Difficulty"] = ""
    write_metadata(
        root / "Debug",
        debug,
        ["SceneIndex", "name", "filename", "condition", "type", "Difficulty", "Camera"],
    )
    held_out = scene_rows(root / "HeldOut", 9, "25")
    write_metadata(root / "HeldOut", held_out, ["file_name"])
    return root

"""Fake clip and probe records that satisfy the specs, determined by their arguments: stand-ins
for rendered ones (``render.generate_clip``, ``generate_probe``) in the store's and the data
pipeline's tests."""

import numpy as np

from voe_lightning import specs


def _video(rng: np.random.Generator, num_frames: int, height: int, width: int):
    """A textured floor with a square sliding over it: compresses like a rendered video."""
    yy, xx = np.mgrid[0:height, 0:width]
    checker = ((xx // 8 + yy // 8) % 2) * 40 + rng.integers(90, 140)
    floor = np.stack([checker, checker + yy, checker + xx // 2], -1).astype(np.uint8)
    frames = np.repeat(floor[None], num_frames, 0)
    mask = np.zeros((num_frames, height, width), np.uint8)
    size = max(2, height // 6)
    x, y = rng.integers(0, width - size), rng.integers(0, height - size)
    color = rng.integers(0, 256, 3, dtype=np.uint8)
    for t in range(num_frames):
        left = (x + 2 * t) % (width - size)
        frames[t, y : y + size, left : left + size] = color
        mask[t, y : y + size, left : left + size] = 1
    return frames, mask


def _objects(rng: np.random.Generator, mask: np.ndarray) -> np.ndarray:
    """Object states of ``_video``'s square (id 1, a box): random pose, its mask's share."""
    objects = np.zeros((len(mask), specs.OBJECT_SLOTS), specs.OBJECT_STATE_DTYPE)
    square = objects[:, 1]
    square["position"] = rng.normal(size=(len(mask), 3))
    square["orientation"] = (1.0, 0.0, 0.0, 0.0)
    square["size"] = rng.uniform(0.1, 0.3, 3)
    square["shape_label"] = specs.OBJECT_SHAPES.index("box")
    square["color"] = rng.random(3)
    square["visible_fraction"] = (mask == 1).mean(axis=(1, 2))
    return objects


def fake_clip(concept, kind, seed, num_frames=15, height=64, width=64, **_):
    """A clip record satisfying specs.clip_spec, determined by its arguments."""
    rng = np.random.default_rng([seed, specs.CLIP_KINDS.index(kind)])
    frames, mask = _video(rng, num_frames, height, width)
    camera = rng.normal(size=(num_frames, 6))
    return specs.clip_record(
        frames,
        mask,
        camera,
        specs.CONCEPTS.index(concept),
        specs.CLIP_KINDS.index(kind),
        seed,
        _objects(rng, mask),
    )


def fake_probe(concept, variant, seed, num_frames=15, height=64, width=64, **_):
    """A probe record satisfying specs.probe_spec: the square vanishes in the inconsistent
    video from the manipulation frame on."""
    rng = np.random.default_rng([seed, specs.VARIANTS.index(variant)])
    frames, mask = _video(rng, num_frames, height, width)
    objects = _objects(rng, mask)
    manipulation = num_frames // 2
    gone_frames, gone_mask, gone_objects = frames.copy(), mask.copy(), objects.copy()
    gone_frames[manipulation:] = frames[0, :1, :1]
    gone_mask[manipulation:] = 0
    gone_objects[manipulation:] = np.zeros((), specs.OBJECT_STATE_DTYPE)
    return specs.probe_record(
        (frames, mask, objects),
        (gone_frames, gone_mask, gone_objects),
        np.zeros(6),
        specs.CONCEPTS.index(concept),
        specs.VARIANTS.index(variant),
        manipulation,
        seed,
        [1],
    )

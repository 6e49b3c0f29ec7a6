"""Contact sheets: probe pairs (consistent above inconsistent, manipulation frame outlined) and
labelled clip rows, from fresh renders and from a store."""

import numpy as np
import pytest
from helpers.stores import fake_clip, fake_probe
from PIL import Image

from voe_lightning import specs
from voe_lightning.data import contact_sheet, store
from voe_lightning.data.store import render


def _red_pixels(path) -> np.ndarray:
    image = np.asarray(Image.open(path).convert("RGB")).astype(int)
    red = np.array([0xE8, 0x11, 0x2D])
    return np.argwhere(np.abs(image - red).sum(-1) < 40)


def test_probe_pair_rows_and_manipulation_outline(tmp_path):
    probe = fake_probe("solidity", "standard", 3)
    rows = contact_sheet.record_rows(probe)
    assert [row.label for row in rows] == ["consistent", "inconsistent"]
    assert all(row.marked_frame == int(probe["manipulation_frame"]) for row in rows)
    clip_rows = contact_sheet.record_rows(fake_clip("solidity", "no_object", 3))
    assert clip_rows[0].label == "control:\nno object" and clip_rows[0].marked_frame is None

    path = contact_sheet.write_records_sheet(
        [probe, fake_clip("solidity", "example", 1)], tmp_path / "s.png"
    )
    width, height = Image.open(path).size
    assert width > 15 * 64 and height > 3 * 64  # 15 frames a row, three rows
    red = _red_pixels(path)
    assert len(red) > 4 * 64  # the outline around the manipulation frame in both rows
    # The outline sits on the manipulation frame's column (frame 7 of 15).
    columns = red[:, 1]
    strip_left = width - 12 - (15 * 66 - 2) * 1.5
    frame = (np.median(columns) - strip_left) / (66 * 1.5)
    assert int(frame) == int(probe["manipulation_frame"])
    clips_only = contact_sheet.write_records_sheet(
        [fake_clip("solidity", "example", 1)], tmp_path / "c.png"
    )
    assert len(_red_pixels(clips_only)) == 0


def test_store_sheet_shows_each_variant_and_kind(tmp_path, monkeypatch):
    monkeypatch.setattr(render, "generate_clip", fake_clip)
    monkeypatch.setattr(render, "generate_probe", fake_probe)
    root = tmp_path / "data"
    store.generate_dataset(
        root, ("unchangeableness",), train_examples=4, val_pairs=1,
        test_pairs=2, generalization_pairs=0, shard_size=4,
        workers=1, progress=False,
    )  # fmt: skip
    shown = []
    original = contact_sheet.record_rows
    monkeypatch.setattr(contact_sheet, "record_rows", lambda r: shown.append(r) or original(r))
    path = contact_sheet.write_store_sheet(root, "unchangeableness", tmp_path / "u.png")
    assert path.exists()
    variants = specs.STANDARD_VARIANTS["unchangeableness"]
    assert sorted(specs.variant_name(r) for r in shown[: len(variants)]) == sorted(variants)
    assert [specs.CLIP_KINDS[int(r["kind"])] for r in shown[len(variants) :]] == [
        "example",
        "objects_only",
        "screen_only",
    ]


def test_concept_sheet_renders_the_real_scene(tmp_path):
    path = contact_sheet.write_concept_sheet("continuity", tmp_path / "continuity.png", seed=1)
    image = np.asarray(Image.open(path).convert("RGB"))
    assert image.shape[1] > 15 * 64 and len(_red_pixels(path)) > 0
    with pytest.raises(ValueError, match="valid concepts are"):
        contact_sheet.write_concept_sheet("gravity", tmp_path / "x.png")

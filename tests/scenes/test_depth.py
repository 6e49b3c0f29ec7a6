"""What the depth image shows of each id (``scenes.depth``, the records' ``depth``): measured
by hand on a drawn mask, and on rendered probes where each object's box says where it is."""

import numpy as np
import pytest
import torch

from voe_lightning import specs
from voe_lightning.scenes import generate_probe
from voe_lightning.scenes.camera import CameraPose, camera_coordinates
from voe_lightning.scenes.depth import CUT_MARGIN, depth_measures


def test_depth_measures_of_a_drawn_mask():
    """Id 1 (depth 3) is partly covered by id 2 (depth 2), which the frame's right edge cuts;
    the floor (id 0) is farther than both and cuts neither."""
    mask = np.zeros((6, 6), np.uint8)
    depth = np.full((6, 6), 5.0, np.float32)
    mask[1:4, 1:4], depth[1:4, 1:4] = 1, 3.0
    mask[2:5, 3:6], depth[2:5, 3:6] = 2, 2.0
    depth[1, 1] = 2.5  # id 1's nearest pixel
    measures = depth_measures(mask, depth)
    assert measures.shape == (specs.OBJECT_SLOTS, len(specs.DEPTH_MEASURES))
    # id 1: 7 pixels, all on its outline; 3 of them border id 2, which is nearer
    np.testing.assert_allclose(measures[1], [(6 * 3.0 + 2.5) / 7, 2.5, 3 / 7], rtol=1e-6)
    # id 2: 9 pixels, 8 on its outline; the 3 in the last column meet the frame's edge
    np.testing.assert_allclose(measures[2], [2.0, 2.0, 3 / 8], rtol=1e-6)
    assert not measures[0].any() and not measures[3:].any()


def test_a_surface_nearer_by_less_than_the_margin_cuts_nothing():
    mask = np.zeros((5, 5), np.uint8)
    depth = np.full((5, 5), 4.0, np.float32)
    mask[1:4, 1:3], mask[1:4, 3] = 1, 2
    depth[1:4, 3] = 4.0 - CUT_MARGIN / 2
    assert depth_measures(mask, depth)[1, 2] == 0.0
    depth[1:4, 3] = 4.0 - 2 * CUT_MARGIN
    assert depth_measures(mask, depth)[1, 2] == pytest.approx(3 / 6)


@pytest.mark.parametrize("concept", ["object_persistence", "containment"])
def test_rendered_depth_lies_within_each_objects_box(concept):
    """Every id the mask shows has measures, every other none; an object's mean depth lies
    within its box's reach of its centre's depth along the camera's axis, its nearest pixel
    no farther than the mean, its cut share a share."""
    record = generate_probe(concept, "standard", 0)
    for name in ("consistent", "inconsistent"):
        video = record[name]
        depth, objects = video["depth"], video["objects"]
        shown = (
            torch.stack(
                [
                    torch.bincount(m.flatten().long(), minlength=specs.OBJECT_SLOTS)
                    for m in video["mask"]
                ]
            )
            > 0
        )
        shown[:, 0] = False
        assert torch.equal(depth.abs().sum(-1) > 0, shown), f"{name}: measures where no id shows"
        for t, slot in shown.nonzero().tolist():
            pose = CameraPose(
                tuple(record["camera"][t, :3].tolist()), *record["camera"][t, 3:].tolist()
            )
            centre = camera_coordinates(pose, objects["position"][t, slot].numpy())[2]
            reach = float(objects["size"][t, slot].norm())
            mean, near, cut = depth[t, slot].tolist()
            assert abs(mean - centre) <= reach + 0.01, f"{name} frame {t} id {slot}"
            assert 0 < near <= mean + 1e-5 and 0.0 <= cut <= 1.0

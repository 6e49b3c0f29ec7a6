"""``analyze emergence``: the validation quadruplet t over training per concept, and the step
from which the verdict's rule holds on."""

import numpy as np
import pytest
from torch.utils.tensorboard import SummaryWriter

from voe_lightning.analysis.emergence import emergence, first_voe_step, read_quadruplet_curves


def _run(path, t_values, halves):
    writer = SummaryWriter(str(path / "version_0"))
    for step, (t, (first, second)) in enumerate(zip(t_values, halves), start=1):
        prefix = "voe/continuity/quadruplet"
        p = 0.5 if t < 3 else 1e-4
        for name, value in (
            ("t", t),
            ("p_value", p),
            ("n", 24),
            ("first_half", first),
            ("second_half", second),
        ):
            writer.add_scalar(f"{prefix}/{name}", value, step * 250)
        writer.add_scalar("voe/continuity/standard/t", t, step * 250)  # not a quadruplet row
    writer.close()


def test_emergence_reads_the_quadruplet_rows_and_finds_where_voe_holds_on(tmp_path):
    _run(tmp_path / "a", [0.5, 4.0, 1.0, 5.0, 6.0], [(1, 1), (1, 1), (1, 1), (1, -1), (1, 1)])
    curves = read_quadruplet_curves(tmp_path / "a")
    assert list(curves) == [("continuity", "quadruplet")]
    np.testing.assert_array_equal(
        curves[("continuity", "quadruplet")]["t"][0], [250, 500, 750, 1000, 1250]
    )
    # significant at 500, lost at 750, a negative half at 1000: it holds on from 1250
    assert first_voe_step(curves[("continuity", "quadruplet")], 0.01) == 1250
    _run(tmp_path / "b", [4.0, 5.0, 2.0], [(1, 1)] * 3)
    assert (
        first_voe_step(read_quadruplet_curves(tmp_path / "b")[("continuity", "quadruplet")], 0.01)
        is None
    )
    out = emergence(
        [f"seed 0={tmp_path / 'a'}", str(tmp_path / "b")], tmp_path / "e.png", alpha=0.01
    )
    assert out.stat().st_size > 0


def test_emergence_names_a_run_without_quadruplet_rows(tmp_path):
    writer = SummaryWriter(str(tmp_path / "old" / "version_0"))
    writer.add_scalar("voe/continuity/standard/t", 1.0, 1)
    writer.close()
    with pytest.raises(ValueError, match="has no voe/<concept>/quadruplet"):
        emergence([str(tmp_path / "old")], tmp_path / "e.png", alpha=0.01)

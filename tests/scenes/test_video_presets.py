"""Probes at the harnesses' lengths (``generate --preset``/``--fps``, docs/benchmarks.md):
every concept draws valid probe pairs at each preset's frames and frame rate (frames identical
through the manipulation frame, the manipulated object hidden there, a real difference after:
``test_scene_validity``'s checks), and a frame k of a clip made at a frame rate shows the
scene at k / fps s. Frame size only matters to the views, so most cases run at 32 x 32; one
case per preset at its full size is marked slow."""

import dataclasses

import mujoco
import numpy as np
import pytest
from helpers.probes import check_probe_pair

from voe_lightning import specs
from voe_lightning.data.video_presets import PRESETS
from voe_lightning.scenes import CONCEPTS, generate_probe
from voe_lightning.scenes.builder import SceneBuilder
from voe_lightning.scenes.camera import CameraPose, VideoOptions

#: Each concept's first quadruplet (both halves: one scene draw), and continuity's own probe.
VARIANTS = {
    concept: next(iter(rows.values())) + (("paper",) if concept == "continuity" else ())
    for concept, rows in specs.QUADRUPLETS.items()
}
LONG_PRESETS = [name for name in PRESETS if name != "paper"]  # paper: test_scene_validity's
SEEDS = (0, 1)


def check_valid_probe(record, concept: str, variant: str, where: str) -> None:
    """test_scene_validity's checks of one pair (``check_probe_pair``), its manipulation
    frame inside the clip."""
    m = int(record["manipulation_frame"])
    assert 0 < m < record["consistent", "frames"].shape[0] - 1, f"{where}: manipulation frame {m}"
    check_probe_pair(record, concept, variant, where)


def _probes(concept: str, video: VideoOptions, seeds=SEEDS):
    for seed in seeds:
        for variant in VARIANTS[concept]:
            yield seed, variant, generate_probe(concept, variant, seed, **dataclasses.asdict(video))


#: (preset, concept, seed): two seeds a concept at each preset; the 480-frame preset's second
#: seed is slow (the cases take about 55 s on a 2-core CPU without it).
LENGTH_CASES = [
    pytest.param(
        preset, concept, seed,
        marks=pytest.mark.slow if preset == "intphys2_vjepa2" and seed else (),
        id=f"{preset}-{concept}-{seed}",
    )
    for preset in LONG_PRESETS
    for concept in CONCEPTS
    for seed in SEEDS
]  # fmt: skip


@pytest.mark.parametrize("preset,concept,seed", LENGTH_CASES)
def test_every_concept_draws_valid_probes_at_each_preset_length(preset, concept, seed):
    chosen = PRESETS[preset]
    video = VideoOptions.at_fps(chosen.fps, chosen.num_frames, 32, 32)
    for _, variant, record in _probes(concept, video, seeds=(seed,)):
        assert record["consistent", "frames"].shape == (chosen.num_frames, 32, 32, 3)
        check_valid_probe(record, concept, variant, f"{preset} {concept}/{variant} seed {seed}")


@pytest.mark.slow
@pytest.mark.parametrize(
    "preset,concept",
    [("intphys", "object_persistence"), ("intphys2_vjepa", "solidity"),
     ("intphys2_vjepa2", "containment")],
)  # fmt: skip
def test_a_preset_at_its_full_size_draws_valid_probes(preset, concept):
    video = PRESETS[preset].video()
    for seed, variant, record in _probes(concept, video, seeds=(0,)):
        assert record["consistent", "frames"].shape == (
            video.num_frames, video.height, video.width, 3,
        )  # fmt: skip
        check_valid_probe(record, concept, variant, f"{preset} {concept}/{variant} seed {seed}")


def _falling_ball(video: VideoOptions):
    builder = SceneBuilder(np.random.default_rng(0), video, CameraPose())
    builder.add_primitive("ball", "sphere", [0.2], [0.0, 0.0, 2.5], "red")
    return builder.build()


@pytest.mark.parametrize("fps,num_frames", [(5, 15), (100 / 3, 100), (160, 480), (7, 20)])
def test_frame_k_shows_the_scene_at_k_over_fps_seconds(fps, num_frames):
    """A ball falls from rest: frame k is rendered at simulation time k / fps exactly (the
    step divides the frame period), and its recorded position is the simulation's then."""
    video = VideoOptions.at_fps(fps, num_frames, 32, 32)
    assert video.fps == pytest.approx(fps) and video.timestep <= 0.01
    sim = _falling_ball(video)
    times: list[float] = []
    _, _, objects = sim.record(num_frames, lambda s, frame: times.append(s.data.time))
    np.testing.assert_allclose(times, np.arange(num_frames) / fps, rtol=0, atol=1e-9)
    ball = sim.mask_id("ball")
    reference = _falling_ball(video)  # stepped alone, one physics step at a time
    for k in range(num_frames):
        while reference.data.time < k / fps - 1e-9:
            reference.step()
        assert reference.data.time == pytest.approx(k / fps, abs=1e-9)
        mujoco.mj_forward(reference.model, reference.data)  # positions of the state now
        np.testing.assert_array_equal(
            objects["position"][k, ball], reference.position("ball").astype(np.float32)
        )
    k = int(0.5 * fps)  # in free fall still (it lands about 0.68 s in)
    fallen = 2.5 - float(objects["position"][k, ball, 2])
    assert fallen == pytest.approx(9.81 * (k / fps) ** 2 / 2, rel=0.06)

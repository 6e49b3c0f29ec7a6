"""``generate --fps`` and ``--preset`` (probes at a harness's lengths, docs/benchmarks.md): the
frame rate sets the clip's length and the physics step, the manifest records them and a store
of another rate is refused, a preset sets its values (flags given beside it win), bad names and
rates are refused in one line before any work, and the default is byte for byte the store it
was before frame rates (with ``--fps 5`` and ``--preset paper`` the same bytes again)."""

import math
from pathlib import Path

import pytest
from helpers.stores import fake_clip, fake_probe

from voe_lightning import specs
from voe_lightning.cli import main
from voe_lightning.data import generate, store
from voe_lightning.data.store import render
from voe_lightning.data.video_presets import PRESETS, check_preset
from voe_lightning.scenes.camera import DURATIONS, MAX_TIMESTEP, VideoOptions

TINY = dict(
    train_examples=2, val_pairs=1, test_pairs=1, generalization_pairs=0, shard_size=4,
    workers=1, progress=False,
)  # fmt: skip
#: The same as command-line words (one concept, one pair per probe split, 32 x 32 frames).
TINY_ARGV = [
    "--concepts", "[continuity]", "--train_examples", "2", "--val_pairs", "1",
    "--test_pairs", "1", "--generalization_pairs", "0", "--shard_size", "4", "--workers", "1",
    "--progress", "false",
]  # fmt: skip


@pytest.fixture
def fakes(monkeypatch):
    """Fast structured records instead of the MuJoCo scenes; the video options each got."""
    asked = []

    def clip(concept, kind, seed, **options):
        asked.append(options)
        return fake_clip(concept, kind, seed, **options)

    def probe(concept, variant, seed, **options):
        asked.append(options)
        return fake_probe(concept, variant, seed, **options)

    monkeypatch.setattr(render, "generate_clip", clip)
    monkeypatch.setattr(render, "generate_probe", probe)
    return asked


def test_the_paper_rate_is_the_default_video_field_for_field():
    assert VideoOptions.at_fps(5) == VideoOptions()
    assert VideoOptions.at_fps(5, 15, 32, 48) == VideoOptions(15, 32, 48)
    assert VideoOptions().fps == 5


@pytest.mark.parametrize("fps,num_frames", [(5, 15), (10, 30), (100 / 3, 100), (160, 480), (7, 20)])
def test_the_step_divides_the_frame_period(fps, num_frames):
    video = VideoOptions.at_fps(fps, num_frames)
    period = 1 / fps
    assert video.duration == pytest.approx(num_frames / fps) and video.fps == pytest.approx(fps)
    assert video.timestep <= MAX_TIMESTEP
    assert video.steps_per_frame * video.timestep == pytest.approx(period, rel=1e-12)
    # the fewest equal steps of at most MAX_TIMESTEP
    assert video.steps_per_frame == math.ceil(period / MAX_TIMESTEP - 1e-9)


def test_fps_sets_the_clip_length_the_manifest_records_and_another_rate_is_refused(tmp_path, fakes):
    summary = store.generate_dataset(
        tmp_path, ("continuity",), num_frames=30, height=24, width=24, fps=10, **TINY
    )
    video = store.read_manifest(tmp_path)["video"]
    assert video == {"num_frames": 30, "height": 24, "width": 24, "duration": 3.0,
                     "timestep": 0.01}  # fmt: skip
    assert VideoOptions(**video).fps == 10  # what export writes as the rate
    assert {options["timestep"] for options in fakes} == {0.01}
    assert store.verify(summary.root) == []
    assert (
        store.ensure_dataset(
            tmp_path,
            concepts=("continuity",),
            num_frames=30,
            height=24,
            width=24,
            fps=10,
            **TINY,
        )  # fmt: skip
        is None
    )
    # The same frames at another rate is another store (its manifest check names the change).
    with pytest.raises(
        store.ManifestMismatchError,
        match=r"video.duration: stored 3.0, asked 2.5",
    ):
        store.generate_dataset(
            tmp_path, ("continuity",), num_frames=30, height=24, width=24, fps=12, **TINY
        )
    # A store made without a rate is one of 3 s clips: the same as asking for num_frames / 3.
    assert (
        store.generate_dataset(
            tmp_path, ("continuity",), num_frames=30, height=24, width=24, **TINY
        ).shards_generated
        == 0
    )


def test_a_preset_sets_its_values_and_flags_beside_it_win(tmp_path, fakes):
    for name, preset in PRESETS.items():
        assert generate._with_preset(name, None, None, None, None) == (
            preset.num_frames, preset.height, preset.width, preset.fps,
        )  # fmt: skip
        video = preset.video()
        assert video.duration == pytest.approx(3.0) and check_preset(name) is preset
    assert (PRESETS["intphys"].num_frames, PRESETS["intphys"].height) == (100, 288)
    assert PRESETS["intphys2_vjepa2"].video().num_frames // 10 == 48  # 48 frames at step 10
    assert PRESETS["intphys2_vjepa"].video().num_frames // 10 == 16
    assert generate._with_preset(None, None, None, None, None) == (15, 64, 64, None)
    assert generate._with_preset("intphys", None, 32, 40, 25.0) == (100, 32, 40, 25.0)
    root = tmp_path / "data"
    main(["generate", "--root", str(root), *TINY_ARGV, "--preset", "intphys",
          "--height", "32", "--width", "32"])  # fmt: skip
    assert store.read_manifest(root)["video"] == {
        "num_frames": 100, "height": 32, "width": 32, "duration": 3.0, "timestep": 0.01,
    }  # fmt: skip
    assert store.open_split(root, "continuity", "test")[0]["consistent", "frames"].shape == (
        100, 32, 32, 3,
    )  # fmt: skip


@pytest.mark.parametrize(
    "words,message",
    [
        (["--preset", "bogus"], "error: --preset: expected one of paper, intphys, "
         "intphys2_vjepa, intphys2_vjepa2, got bogus"),
        (["--fps", "0"], "error: fps must be a positive number of frames per second (the "
         "paper's is 5: 15 frames in 3 s), got 0.0"),
        (["--fps", "-5"], "got -5.0"),
        (["--fps", "inf"], "got inf"),
        (["--fps", "nan"], "error: --fps: expected a number (float), got nan"),
        (["--fps", "1"], "error: 15 frames at 1 fps last 15 s; the scenes are timed for the "
         "paper's 3 s and drawn in 2.5 to 4.5 s: give an fps from 3.33333 to 6 (e.g. 5) or "
         "fewer or more frames"),
        (["--preset", "intphys", "--num_frames", "50"], "50 frames at 33.3333 fps last 1.5 s"),
    ],
)  # fmt: skip
def test_a_bad_preset_or_rate_is_one_line_before_any_work(tmp_path, capsys, fakes, words, message):
    root = tmp_path / "data"
    with pytest.raises(SystemExit) as raised:
        main(["generate", "--root", str(root), *TINY_ARGV, *words])
    assert raised.value.code == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and message in errors[0], errors
    assert not root.exists() and fakes == []


def test_bad_names_and_rates_are_refused_in_python_too(tmp_path):
    with pytest.raises(ValueError, match="unknown preset 'bogus'; valid presets are: paper, "
                       "intphys, intphys2_vjepa, intphys2_vjepa2"):  # fmt: skip
        generate.generate(tmp_path, preset="bogus")  # type: ignore[arg-type]
    for bad in (0, -1.0, math.inf, math.nan, True, "5"):
        with pytest.raises(ValueError, match=rf"fps must be a positive number .*got {bad!r}"):
            store.generate_dataset(tmp_path, ("continuity",), fps=bad, **TINY)
    low, high = DURATIONS
    with pytest.raises(ValueError, match=r"last 5 s; .* drawn in 2.5 to 4.5 s"):
        store.generate_dataset(tmp_path, ("continuity",), fps=3, **TINY)
    assert (low, high) == (2.5, 4.5) and not list(tmp_path.iterdir())


def _shard_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*.voe"))}


def test_the_default_fps_5_and_the_paper_preset_write_the_same_bytes(tmp_path):
    """MuJoCo: the three ways to ask for the paper's clips render the same shards and
    manifest (before frame rates existed, generate wrote these bytes too: the default keeps
    ``VideoOptions()`` exactly)."""
    options = dict(concepts=["continuity"], height=32, width=32, **TINY)
    stores = {
        "default": {},
        "fps 5": {"fps": 5.0},
        "preset paper": {"preset": "paper", "height": 32, "width": 32},
    }
    written = {}
    for name, extra in stores.items():
        root = tmp_path / name.replace(" ", "_")
        generate.generate(root, **{**options, **extra})
        written[name] = (_shard_bytes(root), (root / store.MANIFEST_NAME).read_bytes())
    assert len(written["default"][0]) == 3  # train, val and test
    assert written["fps 5"] == written["default"] == written["preset paper"]
    assert store.read_manifest(tmp_path / "default")["video"] == {
        "num_frames": specs.NUM_FRAMES, "height": 32, "width": 32, "duration": 3.0,
        "timestep": 0.01,
    }  # fmt: skip

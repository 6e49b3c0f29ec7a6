"""What a propped plank does after its front edge lands (round eighteen): over object
persistence's test probes, the video in which the plank ends propped (``settling_surprise``'s
choice), how many frames it still turns by more than 0.05 rad, how often its centre rises by more
than 1 cm, and how much its turn changes from frame to frame against the turn itself (a steady
turn would give 0); then, regenerating standard probes with softer contacts or a finer physics
step (``--settings``), how much it turns after landing (``cue_through_violation.plank_settling``).

    python experiments/plank_pivot.py --root data/cpu --settings default tc0.04 dr2 dr4 dt0.005
"""

import argparse
from unittest import mock

import numpy as np
from cue_through_violation import landing_frame, plank_settling

from voe_lightning import specs
from voe_lightning.data.store import open_split
from voe_lightning.scenes import builder, generate_probe, rendering


def propped(record):
    """The objects of the probe video whose plank ends propped on the object."""
    standard = specs.VARIANTS[int(record["variant"])] == "standard"
    return record["consistent" if standard else "inconsistent"]["objects"]


def after_landing(objects, m: int) -> tuple[np.ndarray, float] | None:
    """The plank's turn per frame after it lands (rad) and how far its centre rises above its
    height at landing (m); None if it never lands."""
    plank = int(objects["size"][0].amax(-1).argmax())
    position = objects["position"][:, plank].double().numpy()
    orientation = objects["orientation"][:, plank].double().numpy()
    landed = landing_frame(position[:, 2], m)
    if landed is None:
        return None
    cosine = np.abs((orientation[landed + 1 :] * orientation[landed:-1]).sum(-1)).clip(0.0, 1.0)
    return 2.0 * np.arccos(cosine), float((position[landed + 1 :, 2] - position[landed, 2]).max())


def staged(setting: str):
    """``rendering.stage`` with the default geom's contact (``tcT``: solref time constant T s;
    ``drR``: damping ratio R) changed; ``default`` and ``dtS`` (a timestep) leave it."""

    def stage(rng, video, floor_pattern=None):
        spec = rendering.stage(rng, video, floor_pattern)
        if setting.startswith("tc"):
            spec.default.geom.solref = [float(setting[2:]), 1.0]
        elif setting.startswith("dr"):
            spec.default.geom.solref = [0.02, float(setting[2:])]
        return spec

    return stage


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument(
        "--settings",
        nargs="*",
        default=[],
        help="default, tcT (solref time constant), drR (damping ratio), dtS (timestep)",
    )
    parser.add_argument("--probes", type=int, default=40, help="standard probes per setting")
    args = parser.parse_args()
    turns, rises = [], []
    for record in open_split(args.root, "object_persistence", "test"):
        if specs.VARIANTS[int(record["variant"])] in specs.STANDARD_VARIANTS["object_persistence"]:
            found = after_landing(propped(record), int(record["manipulation_frame"]))
            if found is not None:
                turns.append(found[0])
                rises.append(found[1])
    changes = sum(np.abs(np.diff(turn)).sum() for turn in turns)
    print(
        f"{len(turns)} propped videos: frames turning > 0.05 rad after landing, median "
        f"{np.median([(turn > 0.05).sum() for turn in turns]):.0f}; centre rising > 1 cm: "
        f"{np.mean(np.array(rises) > 0.01):.0%}; sum |change of turn| / sum turn: "
        f"{changes / sum(turn[1:].sum() for turn in turns):.2f}"
    )
    for setting in args.settings:
        options = {"height": 32, "width": 32}
        if setting.startswith("dt"):
            options["timestep"] = float(setting[2:])
        settled = []
        with mock.patch.object(builder, "stage", staged(setting)):
            for seed in range(args.probes):
                record = generate_probe("object_persistence", "standard", 5000 + seed, **options)
                settled.append(
                    plank_settling(
                        record["consistent"]["objects"], int(record["manipulation_frame"])
                    )["turn"]
                )
        print(
            f"{setting}: median turn after landing {np.median(settled):.2f} rad over "
            f"{len(settled)} standard probes"
        )


if __name__ == "__main__":
    main()

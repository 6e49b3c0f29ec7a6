"""The scene dispatch: every concept has one scene module in ``scenes.SCENES``, and each module
offers what ``ConceptScene`` names with the Protocol's signatures (mypy checks the same when it
types ``SCENES``; this keeps the check where the tests run)."""

import inspect

import pytest

from voe_lightning import specs
from voe_lightning.scenes import SCENES, ConceptScene, camera, check_video, concept_scene

METHODS = [
    name
    for name, member in vars(ConceptScene).items()
    if inspect.isfunction(member) and not name.startswith("_")
]


def test_every_concept_has_its_own_scene_module():
    assert list(SCENES) == list(specs.CONCEPTS)
    assert [module.__name__ for module in SCENES.values()] == [
        f"voe_lightning.scenes.{concept}" for concept in specs.CONCEPTS
    ]


@pytest.mark.parametrize("concept", specs.CONCEPTS)
def test_each_scene_module_has_the_protocol_signatures(concept):
    scene = concept_scene(concept)
    assert set(METHODS) == {"check_video", "clip", "probe"}
    for name in METHODS:
        wanted = inspect.signature(getattr(ConceptScene, name))
        wanted = wanted.replace(parameters=list(wanted.parameters.values())[1:])  # less self
        assert inspect.signature(getattr(scene, name)) == wanted, f"{concept}.{name}"
    assert isinstance(scene.CAMERA, camera.CameraRange)


def test_only_solidity_and_continuity_limit_the_video():
    """The scenes of every concept render any video length but solidity's (whose probes need a
    frame late enough) and continuity's (whose ball is seen in two frames before the screen)."""
    for concept in set(specs.CONCEPTS) - {"solidity", "continuity"}:
        check_video(concept, num_frames=4)
    for concept in ("solidity", "continuity"):
        with pytest.raises(ValueError, match="num_frames >="):
            check_video(concept, num_frames=4)
    check_video("continuity", num_frames=8)


def test_an_unknown_concept_is_refused_with_the_valid_ones():
    with pytest.raises(ValueError, match="valid concepts are"):
        concept_scene("gravity")

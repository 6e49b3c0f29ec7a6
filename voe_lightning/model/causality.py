"""The causality check every report and validation run makes (docs/architecture.md §7, DESIGN.md
§5): a probe pair's two videos are byte-identical before their first difference (at least
through ``manipulation_frame``), so a causal model's per-frame surprise is identical there.
Where it differs beyond float noise, the model reads frames after t (a user's callable scoring
frame t from t..t+1, or giving every frame the video's total), its relative surprise may carry
the answer, and no verdict is given.
``voe_lightning.stats.causality`` holds the finding (``Causality``) and the check of one batch
of pairs (``check_prefix``); here ``check_model`` runs a model through the whole protocol
(``tests/test_causality.py``'s two checks), and ``check_causality`` (``python -m voe_lightning
check-causality``) does so on generated probes for a user's model."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.model.base import SurpriseModel, received_surprise, video_inputs
from voe_lightning.stats.causality import Causality, check_prefix


def check_model(
    model: SurpriseModel, probes: Any, concept: str | None = None
) -> tuple[Causality, Causality]:
    """The causality protocol of ``model`` (a ``SurpriseModel``) on a batch of probe pairs:
    per-frame surprise identical before the first frame at which each pair's inputs differ
    (``check_prefix`` of ``probe_step``'s ``inputs_differ``), and each inconsistent video's surprise up to frame t
    unchanged when the video (frames, masks, camera, object states) is cut after t, for every t
    (counted once per video and frame; each answer copied as received, so a model reusing one
    output buffer cannot overwrite the whole video's). Surprise that is not finite (NaN equals
    NaN nowhere, so an all-NaN model would pass) cannot be checked: a ValueError naming the
    model (and ``concept``)."""
    frames = probes["inconsistent", "frames"]
    with torch.no_grad():
        scored = model.probe_step(probes)
        _check_finite(
            model,
            concept,
            scored["surprise_consistent"],
            scored["surprise_inconsistent"],
        )
        prefix = check_prefix(
            scored["surprise_consistent"],
            scored["surprise_inconsistent"],
            scored["manipulation_frame"],
            scored["inputs_differ"],
        )
        inputs = video_inputs(probes, "inconsistent", model.inputs_read())
        whole = received_surprise(model.surprise(frames, **inputs), model_name(model))
        cut = Causality()
        for t in range(frames.shape[1] - 1):
            through = {name: _through(value, t) for name, value in inputs.items()}
            part = received_surprise(
                model.surprise(frames[:, : t + 1], **through), model_name(model)
            )
            _check_finite(model, concept, whole, part)
            cut = cut.merge(check_prefix(whole[:, : t + 1], part, torch.full((len(frames),), t)))
    return prefix, cut


def model_name(model: SurpriseModel) -> str:
    """The model's class, and a ``CallableModel``'s callable: 'CallableModel of my.fn'."""
    function = getattr(model, "hparams", {}).get("function")
    name = type(model).__name__
    return f"{name} of {function}" if isinstance(function, str) else name


def _check_finite(model: SurpriseModel, concept: str | None, *surprises: torch.Tensor) -> None:
    """A ValueError when any of ``surprises`` is NaN or infinite: causality cannot be checked."""
    values = torch.cat([surprise.detach().reshape(-1).double().cpu() for surprise in surprises])
    bad = int((~torch.isfinite(values)).sum())
    if bad:
        where = f" on {concept}'s probes" if concept else ""
        raise ValueError(
            f"{model_name(model)}'s causality cannot be checked: its surprise is not finite"
            f"{where} ({bad:,} of {values.numel():,} per-frame values NaN or infinite); the "
            "check compares finite surprise (NaN would pass as identical): make the model's "
            "surprise finite"
        )


def _through(value: Any, t: int) -> Any:
    """A batch of videos' input [B, T, ...] through frame t: a tensor, or object states (a
    TensorDict of batch [B] whose leaves are [B, T, ...])."""
    if isinstance(value, TensorDictBase):
        return value.apply(lambda leaf: leaf[:, : t + 1])
    return value[:, : t + 1]


def check_causality(
    model: SurpriseModel,
    concepts: list[specs.Concept] | None = None,
    seeds: int = 2,
    size: int = 32,
    num_frames: int = 15,
) -> bool:
    """Run a model through the causality protocol on generated probe pairs.

    Surprise at frame t may read frames up to t only: per concept, each pair's per-frame
    surprise must be identical before its first difference (the two videos are), and a
    video cut after t must keep its surprise up to t. Prints one line per check and concept;
    refuses a model that fails (exit status 2). The model is checked as built (causality is
    a property of its computation, not of its weights).

    Args:
        model: the model, e.g. ``--model voe_lightning.model.CallableModel
            --model.init_args.function my_package.surprise``.
        concepts: concepts whose probes to generate (default: all five).
        seeds: probe pairs per concept and variant.
        size: height and width of the generated videos.
        num_frames: frames per video.
    """
    from voe_lightning.scenes import PROBE_VARIANTS, generate_probe  # MuJoCo: only when run

    if seeds < 1:
        raise ValueError(f"seeds must be an integer of at least 1, got {seeds}")
    model.eval()
    failed = []
    for concept in concepts or specs.CONCEPTS:
        probes = torch.stack(
            [
                generate_probe(
                    concept, variant, seed, height=size, width=size, num_frames=num_frames
                )
                for variant in PROBE_VARIANTS[concept]
                for seed in range(seeds)
            ]
        )
        checks = ("pairs before their first difference", "videos cut after each frame t")
        for check, unit, found in zip(
            checks, ("pairs", "cuts"), check_model(model, probes, concept)
        ):
            print(f"{concept}, {check}: {found.counted(unit)}")
            if not found.causal:
                failed.append(f"{concept} ({check})")
    if failed:
        raise ValueError(
            f"{type(model).__name__} is not causal: its surprise at frame t reads "
            f"later frames in {', '.join(failed)}"
        )
    return True

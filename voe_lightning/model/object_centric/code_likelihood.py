"""The likelihood of a frame's object codes under the visibility-aware slot dynamics
(``SlotDynamics.rollout``), term by term, and its rectified excess surprisal: the surprise of
the object-centric model with ``surprise: likelihood``, scored as the positive control scores
object states (``object_state.ObjectStateModel._per_frame``)."""

from __future__ import annotations

import torch

from voe_lightning.model.likelihood import bernoulli_nll, gaussian_nll, rectified_excess

#: The terms of what frame t shows: each known slot's visibility, its code where it is seen,
#: whether a new object appears, and each newcomer's code.
TERMS = ("visibility", "code", "appear", "newcomer_code")
#: The terms that score a code (a Gaussian over all its dimensions).
CODE_TERMS = ("code", "newcomer_code")


def frame_terms(
    prediction: dict[str, torch.Tensor],
    codes: torch.Tensor,
    seen: torch.Tensor,
    visible: torch.Tensor,
) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
    """(negative log-likelihood, entropy of the prediction) of each term of ``TERMS`` for the
    frames 1..T-1, each [B, T - 1, S] (``appear`` [B, T - 1]; 0 where a term does not apply),
    from ``prediction`` (``SlotDynamics.rollout``: step t predicts t + 1), the perceived
    ``codes`` [B, T, S, C], ``seen`` [B, T, S] (the slot's id was seen by t) and ``visible``
    [B, T, S] (its mask is not empty at t). A slot known before t is scored on whether it is
    seen at t and, where seen, on its code; a slot first seen at t is a newcomer."""
    known = seen[:, :-1].float()
    shown = visible[:, 1:].float()
    new = (seen[:, 1:] & ~seen[:, :-1]).float()
    terms: dict[str, tuple[tuple[torch.Tensor, torch.Tensor], torch.Tensor | float]] = {
        "visibility": (bernoulli_nll(prediction["seen_logit"][:, :-1], shown), known),
        "code": (
            gaussian_nll(codes[:, 1:], prediction["mean"][:, :-1], prediction["log_std"][:, :-1]),
            known * shown,
        ),
        "appear": (bernoulli_nll(prediction["appear_logit"][:, :-1], new.amax(-1)), 1.0),
        "newcomer_code": (
            gaussian_nll(
                codes[:, 1:],
                prediction["newcomer_mean"][:, :-1, None],
                prediction["newcomer_log_std"][:, :-1, None],
            ),
            new,
        ),
    }
    return {
        name: (nll * weight, entropy * weight) for name, ((nll, entropy), weight) in terms.items()
    }


def negative_log_likelihood(
    terms: dict[str, tuple[torch.Tensor, torch.Tensor]],
) -> dict[str, torch.Tensor]:
    """Each term's negative log-likelihood summed over slots, [B, T - 1]."""
    return {name: _per_frame(nll) for name, (nll, _) in terms.items()}


def excess_surprisal(terms: dict[str, tuple[torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    """Each frame's rectified excess surprisal [B, T - 1]: per slot and term, its negative
    log-likelihood less its entropy, where positive, summed. Only what is less likely than
    the model expected counts, so a video showing more objects does not read as less surprising
    for each well-predicted object
    (docs/architecture.md §7, "Surprise as rectified excess")."""
    total = sum(_per_frame(rectified_excess(nll, entropy)) for nll, entropy in terms.values())
    assert isinstance(total, torch.Tensor)  # frame_terms gives every term of TERMS
    return total


def _per_frame(values: torch.Tensor) -> torch.Tensor:
    """A term [B, T - 1, S] summed over slots, or [B, T - 1] as it is."""
    return values.sum(-1) if values.dim() == 3 else values

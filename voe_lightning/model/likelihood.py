"""The likelihoods the surprise models score what they see with (a diagonal Gaussian, a
mixture of them, a Bernoulli, a categorical), each with the entropy of the prediction, and the
rectified excess surprisal built from the two: a term counts only where what is seen is less
likely than the model expected
(docs/architecture.md §7, "Surprise as rectified excess")."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

LOG_2PI = math.log(2 * math.pi)


def gaussian_nll(
    value: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """-log N(value; mean, exp(log_std)^2) and the entropy of that Gaussian, each summed over
    the last dimension."""
    z = (value - mean) * torch.exp(-log_std)
    entropy = log_std + 0.5 * (LOG_2PI + 1)
    return (0.5 * z.pow(2) + log_std + 0.5 * LOG_2PI).sum(-1), entropy.sum(-1)


def bernoulli_nll(logit: torch.Tensor, value: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """-log Bernoulli(value; sigmoid(logit)) and the entropy of that Bernoulli."""
    return (
        F.binary_cross_entropy_with_logits(logit, value, reduction="none"),
        F.binary_cross_entropy_with_logits(logit, torch.sigmoid(logit), reduction="none"),
    )


def mixture_nll(
    value: torch.Tensor,
    means: torch.Tensor,
    log_std: torch.Tensor,
    logits: torch.Tensor | None,
    hard: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """-log of ``value`` [..., D] under a mixture of diagonal Gaussians (``means`` and
    ``log_std`` [..., K, D], component ``logits`` [..., K] or None for one), and the mixture's
    entropy as sum_k pi_k (H_k - log pi_k): exact for well separated components, at most
    log K too high where they overlap. ``hard``: -log of the best-explaining component's
    weighted density alone (hard EM), so a component learns only from what it explains."""
    nll, entropy = gaussian_nll(value[..., None, :], means, log_std)  # [..., K]
    if logits is None:
        return nll.squeeze(-1), entropy.squeeze(-1)
    log_weight = F.log_softmax(logits, dim=-1)
    joint = log_weight - nll
    return (
        -(joint.amax(-1) if hard else torch.logsumexp(joint, dim=-1)),
        (log_weight.exp() * (entropy - log_weight)).sum(-1),
    )


def categorical_nll(
    logits: torch.Tensor, one_hot: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """-log Categorical(one_hot; softmax(logits)) over the last dimension, and its entropy."""
    log_p = F.log_softmax(logits, dim=-1)
    return -(log_p * one_hot).sum(-1), -(log_p.exp() * log_p).sum(-1)


def rectified_excess(nll: torch.Tensor, entropy: torch.Tensor) -> torch.Tensor:
    """A term's negative log-likelihood less its expectation under the prediction (the
    entropy), where positive: a video showing more well-predicted objects does not read as
    less surprising."""
    return (nll - entropy).clamp(min=0)

"""Any video model as a ``SurpriseModel`` without subclassing: a plain callable frames ->
per-frame surprise, named by its import path, so ``test`` and ``predict`` score it with
``--model voe_lightning.model.CallableModel --model.init_args.function my_pkg.surprise``."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.model.base import SurpriseModel, check_real_surprise


class CallableError(ValueError):
    """A ValueError the user's callable raised, named by its path; the CLI's one line says how
    to see the callable's own traceback."""


def import_callable(path: str) -> Callable[..., Any]:
    """The object ``package.module.name`` names (``package.module:name`` too), checked callable."""
    module_name, _, name = path.replace(":", ".").rpartition(".")
    try:
        function: object = getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError, ValueError) as error:
        raise ValueError(
            f"function {path!r} cannot be imported ({error}); give the dotted path "
            "of a callable, e.g. my_package.models.surprise"
        ) from None
    if not callable(function):
        raise ValueError(f"function {path!r} is a {type(function).__name__}, not a callable")
    return function


def _as_surprise(returned: object) -> torch.Tensor:
    """The callable's surprise as a tensor: a floating dtype as given, any other (integers,
    Python numbers) as float64, so the report's float64 sums lose nothing to rounding."""
    if isinstance(returned, (list, tuple)):
        try:
            return torch.as_tensor(returned, dtype=torch.float64)
        except TypeError:  # complex numbers: refused by name (check_real_surprise)
            surprise = torch.as_tensor(returned)
            if surprise.is_complex():
                return surprise
            raise
    surprise = torch.as_tensor(returned)
    if surprise.is_complex():
        return surprise  # refused by name in CallableModel.surprise (check_real_surprise)
    return surprise if surprise.is_floating_point() else surprise.double()


class CallableModel(SurpriseModel):
    """Wraps ``function(frames) -> surprise``: frames uint8 [B, T, H, W, 3] on this module's
    device, per-frame surprise [B, T] (frame t's from frames up to t only, the protocol's
    causality). The callable owns any weights (loaded from a local path when it is built);
    nothing here is trained, so ``test`` needs no checkpoint. It has no expectation to show:
    ``expected_frames`` are the input frames.

    Args:
        function: import path of the callable, e.g. ``my_package.models.surprise``.
    """

    SURPRISE = "the wrapped model's surprise"

    def __init__(self, function: str):
        super().__init__()
        self.save_hyperparameters()
        self.function = import_callable(function)

    def inputs_read(self) -> frozenset[str]:
        """The function sees the frames only."""
        return frozenset()

    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        try:
            returned = self.function(frames.to(self.device))
        except ValueError as error:  # a user error prints one line: name the callable in it
            raise CallableError(
                f"{self.hparams['function']} raised {type(error).__name__}: {error}"
            ) from error
        try:
            surprise = _as_surprise(returned)
        except (TypeError, ValueError, RuntimeError) as error:  # None, a ragged list
            raise ValueError(
                f"{self.hparams['function']} returned a {type(returned).__name__} that "
                f"is no array of numbers ({error}); expected surprise [B, T] = "
                f"{list(frames.shape[:2])}"
            ) from None
        check_real_surprise(surprise, self.hparams["function"])
        if tuple(surprise.shape) != tuple(frames.shape[:2]):
            raise ValueError(
                f"{self.hparams['function']} returned surprise of shape "
                f"{tuple(surprise.shape)} for frames {tuple(frames.shape)}; expected "
                f"[B, T] = {list(frames.shape[:2])}"
            )
        return surprise

    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        return specs.to_model_input(frames)

    def trajectories(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> dict[str, torch.Tensor]:
        """Surprise and its running total, a course [B, T, 2] (the report's t-SNE figure
        projects courses onto two components)."""
        value = self.surprise(frames)
        return {"surprise": torch.stack([value, value.cumsum(dim=1)], dim=-1)}

"""The model protocol every video model implements (docs/architecture.md §7): per-frame surprise, the
expected frames and the trajectories, so callbacks, reports and the cue audit treat every model
alike; plus what they share: probe steps, frame-count recording and checkpoint safety."""

from __future__ import annotations

import atexit
from abc import ABCMeta, abstractmethod
from collections.abc import Collection
from typing import Any

import torch
from lightning.pytorch import LightningModule
from lightning.pytorch.utilities import rank_zero_warn
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.model.training_monitor import non_finite_message
from voe_lightning.stats.surprise_window import first_difference, video_surprise


def _destroy_process_group() -> None:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()


#: A video's inputs that the protocol's methods do not take: only a model that says it reads
#: one (``inputs_read``) is given it, as a keyword its methods add (``depth``, per mask id what
#: the depth image shows, ``specs.depth_spec``: the object-state model's RGB-D rung).
OPTIONAL_INPUTS = ("depth",)


def video_inputs(
    batch: Any, video: str | None = None, read: Collection[str] = ()
) -> dict[str, Any]:
    """``mask`` and ``objects`` (per-object states, ``specs.objects_spec``) of a clip batch
    (``video=None``) or of one side of a probe batch, and the batch's ``camera``, each when the
    batch has it: keyword arguments of the protocol; also each of the ``OPTIONAL_INPUTS`` a
    model ``read``s (its ``inputs_read``), when the batch has it."""
    nested = isinstance(batch, TensorDictBase)
    keys = set(batch.keys(include_nested=True) if nested else batch.keys())
    inputs = {}
    for name in ("mask", "objects", *(name for name in OPTIONAL_INPUTS if name in read)):
        key = name if video is None else (video, name)
        if key in keys:
            inputs[name] = batch[key]
    if "camera" in keys:
        inputs["camera"] = batch["camera"]
    return inputs


def inputs_read_by(model: Any) -> frozenset[str]:
    """What ``model`` says its surprise reads (``SurpriseModel.inputs_read``); none for a
    module without the protocol."""
    read = getattr(model, "inputs_read", None)
    return frozenset(read()) if callable(read) else frozenset()


def check_real_surprise(surprise: torch.Tensor, source: str) -> torch.Tensor:
    """``surprise`` when it is real numbers held in memory; a ValueError naming ``source``
    (the model class or the callable) and what it returned otherwise: a complex dtype, whose
    imaginary part a cast would drop, a tensor on the meta device, which holds no values, or a
    sparse one, which the statistics cannot index."""
    if surprise.is_meta:
        raise ValueError(
            f"{source} returned surprise on the meta device, a tensor of shape "
            f"{tuple(surprise.shape)} without values: return one holding its numbers, on the "
            "CPU or the frames' device"
        )
    if surprise.layout is not torch.strided:
        raise ValueError(
            f"{source} returned sparse surprise ({surprise.layout}): return a dense tensor "
            "(e.g. its .to_dense())"
        )
    if surprise.is_complex():
        raise ValueError(
            f"{source} returned complex surprise ({surprise.dtype}): surprise is a real "
            "number per frame; return a real floating tensor (e.g. its .abs() or .real, "
            "whichever your model means)"
        )
    return surprise


def inputs_first_difference(
    consistent: dict[str, Any],
    inconsistent: dict[str, Any],
    frames_first: torch.Tensor,
    read: frozenset[str] = frozenset({"mask", "objects"}),
) -> torch.Tensor:
    """The first frame at which each pair's inputs differ, int64 [B]: the earliest of its
    frames' (``frames_first``) and of each of the ``read`` inputs (masks, object states) both
    sides have; a state can differ a frame before the pixels show it. A causal model's surprise
    is identical before it."""
    first = frames_first
    for name in sorted(consistent.keys() & inconsistent.keys() & read):
        one, other = consistent[name], inconsistent[name]
        leaves = (
            zip(one.values(True, True), other.values(True, True))
            if isinstance(one, TensorDictBase)
            else [(one, other)]
        )
        for a, b in leaves:
            first = torch.minimum(first, first_difference(a, b).to(first.device))
    return first


def received_surprise(surprise: torch.Tensor, source: str) -> torch.Tensor:
    """A model's per-frame surprise as the package keeps it: checked real
    (``check_real_surprise``), a copy of its own (a model may return a view of a buffer it
    reuses for the next batch) in float32, or float64 when it is (bf16/fp16 widened exactly,
    so no sum rounds in them; integers as float64, as ``CallableModel`` takes them)."""
    check_real_surprise(surprise, source)
    wide = surprise.dtype == torch.float64 or not surprise.is_floating_point()
    return surprise.to(torch.float64 if wide else torch.float32, copy=True)


def expected_frames_problem(model: Any, expected: Any, frames: torch.Tensor) -> str | None:
    """What is wrong with ``model.expected_frames``' answer ``expected`` for uint8 ``frames``
    [B, T, H, W, 3], in words (None: nothing): it must be a tensor [B, T, 3, H, W]."""
    b, t, h, w = frames.shape[:4]
    wanted = (b, t, 3, h, w)
    got = tuple(expected.shape) if isinstance(expected, torch.Tensor) else None
    if got == wanted:
        return None
    what = f"shape {got}" if got is not None else f"a {type(expected).__name__}"
    return (
        f"{type(model).__name__}.expected_frames returned {what} for frames "
        f"{tuple(frames.shape)}; expected a tensor [B, T, 3, H, W] = {list(wanted)}"
    )


class SurpriseModel(LightningModule, metaclass=ABCMeta):
    """Base of the package's video models. Subclasses implement ``surprise``,
    ``expected_frames`` and ``trajectories`` of uint8 videos ``frames`` [B, T, H, W, 3], given
    optionally their object-id ``mask`` uint8 [B, T, H, W] (0 = background), ``camera``
    poses float [B, T, 6] and ``objects``, the per-object states of ``specs.objects_spec``
    (batched [B, T, K]); a model that needs none of them accepts and ignores them (a subclass
    missing one of the three cannot be built: ABCMeta). ``ARCHITECTURE``
    names the constructor arguments that shape the parameters, which a checkpoint must share;
    ``TRAINING_ONLY`` those that change only how it trains (optimizer, schedules), which
    evaluating a checkpoint may give otherwise: they change nothing it computes.
    ``EVALUATION_ONLY`` those that change only how a trained model scores surprise, no
    parameter and no training, which evaluating a checkpoint may give otherwise and then uses
    instead of the checkpoint's, so one checkpoint can be scored in more than one way."""

    ARCHITECTURE: tuple[str, ...] = ()
    TRAINING_ONLY: tuple[str, ...] = ()
    EVALUATION_ONLY: tuple[str, ...] = ()

    # ----------------------------------------------------------------------------- protocol
    def inputs_read(self) -> frozenset[str]:
        """Which of a video's ``mask`` and ``objects`` its surprise may read (frames and camera
        always): the causality check compares a pair's surprise before the first frame at which
        the frames or one of these differ. Any may, unless a family says it reads fewer. A
        model that names one of the ``OPTIONAL_INPUTS`` here (``depth``) is given it by
        ``video_inputs``, as a keyword of its methods; no other model is."""
        return frozenset({"mask", "objects"})

    @abstractmethod
    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """Per-frame surprise [B, T] (float32); a video's surprise is its sum over frames."""

    @abstractmethod
    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """What the model expected each frame to be given the previous ones [B, T, 3, H, W]
        in [0, 1]."""

    @abstractmethod
    def trajectories(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> dict[str, torch.Tensor]:
        """Named time courses [B, T, D] of the model's state (the t-SNE figure draws them)."""

    def setup(self, stage: str) -> None:
        # Lightning destroys only NCCL process groups at exit. A gloo group (CPU DDP) left
        # alive aborts its process about half the time as it exits ("terminate called
        # without an active exception", pytorch#190489), so every rank destroys it then.
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            atexit.unregister(_destroy_process_group)
            atexit.register(_destroy_process_group)

    # ----------------------------------------------------------------------------- inputs
    @staticmethod
    def _frames_of(batch: TensorDictBase | dict[str, Any]) -> torch.Tensor:
        if "frames" not in batch.keys():
            raise KeyError(
                "a training batch needs 'frames' (uint8 [B,T,H,W,3]); got keys "
                f"{list(batch.keys())}"
            )
        frames: torch.Tensor = batch["frames"]
        return frames

    @staticmethod
    def _clip_length(batch: TensorDictBase | dict[str, Any]) -> int:
        """Frames per clip of a training batch: its frames' count, or, in a batch that holds
        no frames (a state learner's ``train_fields``), its camera poses'."""
        for key in ("frames", "camera"):
            if key in batch.keys():
                length: int = batch[key].shape[1]
                return length
        raise KeyError(
            "a training batch needs 'frames' (uint8 [B,T,H,W,3]) or 'camera' ([B,T,6]); got "
            f"keys {list(batch.keys())}"
        )

    # ----------------------------------------------------------------------------- training
    def _check_finite(self, terms: dict[str, torch.Tensor]) -> None:
        """Stop training on a NaN/inf loss, naming the step and the offending term(s)."""
        names = [name for name in terms if name != "loss"] or list(terms)
        values = torch.stack([terms[name].detach().float() for name in names])
        if not bool(torch.isfinite(values).all()):
            raise FloatingPointError(non_finite_message(self.global_step, names, values.tolist()))

    def on_train_batch_start(self, batch: TensorDictBase, batch_idx: int) -> None:
        """Record the training clips' frame count in ``training_frames`` (saved in
        checkpoints), warning when it replaces another one (a checkpoint's, or a value given)."""
        frames = self._clip_length(batch)
        recorded = self.hparams.get("training_frames")
        if recorded != frames:
            if recorded is not None:
                rank_zero_warn(
                    f"training_frames was {recorded}, the training clips have "
                    f"{frames}: recording {frames}"
                )
            self.hparams["training_frames"] = frames

    # ----------------------------------------------------------------------------- probes
    def probe_step(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """Surprise of both videos of each probe pair (one pass: rows never interact); each
        video's mask and the pair's camera go to the model when the batch has them (and each
        video's ``depth`` to a model that reads it, ``video_inputs``). Also the
        pair's ``first_difference``, the first frame at which its videos differ, where a
        surprise window starts (``voe_lightning.stats.surprise_window``), and ``inputs_differ``,
        the first at which any of its inputs do, before which the causality check compares."""
        consistent = batch["consistent", "frames"]
        inconsistent = batch["inconsistent", "frames"]
        read = self.inputs_read()
        sides = [video_inputs(batch, side, read) for side in ("consistent", "inconsistent")]
        inputs = {
            name: torch.cat([side[name] for side in sides], dim=0)
            for name in sides[0]
            if all(name in side for side in sides)
        }
        surprise = received_surprise(
            self.surprise(torch.cat([consistent, inconsistent], dim=0), **inputs),
            type(self).__name__,
        )
        surprise_consistent, surprise_inconsistent = surprise.split(consistent.shape[0], dim=0)  # type: ignore[no-untyped-call]  # Tensor.split: unannotated in torch
        frames_first = first_difference(consistent, inconsistent)
        return {
            "concept": batch["concept"],
            "variant": batch["variant"],
            "seed": batch["seed"],
            "manipulation_frame": batch["manipulation_frame"],
            "surprise_consistent": surprise_consistent,
            "surprise_inconsistent": surprise_inconsistent,
            "first_difference": frames_first,
            "inputs_differ": inputs_first_difference(sides[0], sides[1], frames_first, read),
        }

    #: Name under which ``validation_step`` logs the consistent probes' mean video surprise.
    VALIDATION_METRIC = "val/surprise"
    #: What a frame's surprise is, for reports.
    SURPRISE = "the model's surprise"

    def validation_step(
        self, batch: TensorDictBase, batch_idx: int, dataloader_idx: int = 0
    ) -> dict[str, torch.Tensor]:
        """Probe surprise for the callbacks; logs ``VALIDATION_METRIC``, the mean per-video
        surprise of the consistent probes (a plain held-out number to monitor)."""
        result = self.probe_step(batch)
        consistent = result["surprise_consistent"]
        self.log(
            self.VALIDATION_METRIC,
            video_surprise(consistent).mean(),
            batch_size=consistent.shape[0],
            add_dataloader_idx=False,
        )
        return result

    def test_step(
        self, batch: TensorDictBase, batch_idx: int, dataloader_idx: int = 0
    ) -> dict[str, torch.Tensor]:
        """Probe surprise for the callbacks (logs nothing itself)."""
        return self.probe_step(batch)

    def predict_step(
        self, batch: TensorDictBase, batch_idx: int, dataloader_idx: int = 0
    ) -> dict[str, torch.Tensor]:
        """Each video's surprise (its sum over frames, float64, and its largest frame's:
        ``surprise_max``) with its ``index`` in the predict dataset, for a prediction writer;
        its mask and camera go along when the batch has them (its depth, to a model that reads
        it)."""
        surprise = received_surprise(
            self.surprise(self._frames_of(batch), **video_inputs(batch, read=self.inputs_read())),
            type(self).__name__,
        ).double()
        return {
            "index": batch["index"],
            "surprise": video_surprise(surprise),
            "surprise_max": surprise.max(-1).values,
        }

    # ----------------------------------------------------------------------------- checkpoints
    def _model_input(self, frames: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor:
        """uint8 [B, T, H, W, 3] -> float [B, T, 3, H, W] on this module's device."""
        return specs.to_model_input(self._checked_frames(frames, image_size))

    def _checked_frames(self, frames: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor:
        """uint8 frames [B, T, H, W, 3] of this model's image size, on its device (refused,
        naming the shape, otherwise)."""
        if not isinstance(frames, torch.Tensor):
            raise TypeError(f"frames must be a uint8 tensor [B, T, H, W, 3], got {type(frames)}")
        expected = (*image_size, 3)
        if frames.dim() != 5 or tuple(frames.shape[-3:]) != expected:
            raise ValueError(
                f"frames must be shaped [B, T, {expected[0]}, {expected[1]}, 3] for this model "
                f"(image_size={image_size}), got {tuple(frames.shape)}"
            )
        return frames.to(self.device)

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """Refuse, naming the file, a checkpoint trained with another architecture (naming the
        differences) or one without hyperparameters whose weights do not fit this model
        (Lightning calls this before loading the weights, which would fail obscurely)."""
        source = getattr(self._trainer, "ckpt_path", None) or "the checkpoint"
        trained = checkpoint.get("hyper_parameters")
        if not trained:
            self._refuse_unfitting_weights(checkpoint.get("state_dict", {}), source)
            return

        def normal(value: Any) -> Any:
            return list(value) if isinstance(value, (list, tuple)) else value

        differences = [
            f"{name}: checkpoint {normal(trained[name])!r}, config {normal(self.hparams[name])!r}"
            for name in self.ARCHITECTURE
            if name in trained and normal(trained[name]) != normal(self.hparams[name])
        ]
        if differences:
            raise ValueError(
                f"{source} was trained with another model architecture than this model's ("
                + "; ".join(differences)
                + f"). Build the model with the checkpoint's arguments "
                f"({type(self).__name__}.load_from_checkpoint, or its run's config.yaml)."
            )

    def _refuse_unfitting_weights(self, state_dict: dict[str, torch.Tensor], source: str) -> None:
        """Without hyperparameters the model was built from the config's arguments alone: say
        so, naming the first tensor that does not fit, instead of torch's mismatch list."""
        ours = {name: list(tensor.shape) for name, tensor in self.state_dict().items()}
        theirs = {name: list(tensor.shape) for name, tensor in state_dict.items()}
        differences = [
            f"{name}: checkpoint {theirs.get(name, 'missing')}, model {ours.get(name, 'missing')}"
            for name in sorted(ours.keys() | theirs.keys())
            if ours.get(name) != theirs.get(name)
        ]
        if differences:
            raise ValueError(
                f"{source} has no hyper_parameters, so the model was built from the config's "
                f"arguments, and its weights do not fit them ({len(differences)} tensors differ, "
                f"e.g. {differences[0]}). Give the model arguments it was trained with (its "
                "run's config.yaml)."
            )

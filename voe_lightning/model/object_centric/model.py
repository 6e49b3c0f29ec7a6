"""The object-centric model after PLATO (Piloto et al. 2022, Figure 3) as a LightningModule:
per-object codes from segmentation masks (perception), slot dynamics with an interaction network
(prediction), trained in two stages of one run, and its object-free twin."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypedDict

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.model.base import SurpriseModel, video_inputs
from voe_lightning.model.object_centric import code_likelihood
from voe_lightning.model.object_centric.networks import build_networks, matching_code_size
from voe_lightning.model.object_centric.perception import autoencoder_terms, compose
from voe_lightning.model.object_centric.slots import (
    MAX_MASK_JUMP,
    Slots,
    object_slots,
    require_mask,
    whole_frame_slot,
)

#: Constructor arguments that shape the parameters: a checkpoint must agree on all of them.
ARCHITECTURE = (
    "image_size",
    "num_slots",
    "code_size",
    "encoder_channels",
    "variational",
    "state_size",
    "relation_sizes",
    "node_sizes",
    "relation_size",
    "use_camera",
    "object_free",
    "object_free_code_size",
    "surprise",
)
#: What a frame's surprise is, per ``surprise`` and ``surprise_space``, for reports.
SURPRISES = {
    ("squared_error", "codes"): "the squared error of the predicted object codes (summed over "
    "the slots seen)",
    ("likelihood", "codes"): "the rectified excess surprisal of the object codes (each term's "
    "negative log-likelihood less its entropy, where positive: every "
    "known object's visibility, its code where seen, and any newcomer's "
    "appearance)",
    ("squared_error", "pixels"): "the squared pixel error of the frame decoded from the "
    "predicted object codes (PLATO-style pixel-space surprise)",
    ("likelihood", "pixels"): "the squared pixel error of the frame decoded from the predicted "
    "object codes, each weighed by its predicted visibility "
    "(pixel-space surprise)",
}


class _Predicted(TypedDict):
    predicted: torch.Tensor


class DynamicsOutputs(_Predicted, total=False):
    """What ``ObjectCentricModel._dynamics`` gives: ``predicted`` always, the rest only
    visibility-aware (``SlotDynamics.rollout``'s ``prediction``, ``code_likelihood``'s
    ``terms``)."""

    prediction: dict[str, torch.Tensor]
    visible: torch.Tensor
    terms: dict[str, tuple[torch.Tensor, torch.Tensor]]


class PassOutputs(DynamicsOutputs):
    """What ``ObjectCentricModel._predict`` gives: the dynamics' outputs and what they came of."""

    x: torch.Tensor
    codes: torch.Tensor
    seen: torch.Tensor
    present: torch.Tensor
    log_visibility: torch.Tensor | None


class ObjectCentricModel(SurpriseModel):
    """PLATO-style model: object slots from the masks (``slots.object_slots``: slot 0 the
    background, then up to ``num_slots`` object ids), a shared per-object autoencoder
    (``perception.Perception``) and a slotted LSTM fed by an interaction network
    (``dynamics.SlotDynamics``) that predicts each slot's next code.

    Training runs two stages in one run: for the first ``perception_steps`` global steps only
    perception trains (reconstruction of the composed frame, the slots' masks and, for a VAE,
    the KL); after, perception is frozen in eval mode, its codes (posterior means) detached,
    and only the dynamics train (by ``surprise``'s loss, below). Parameters of the
    inactive stage get no gradient, so Adam leaves them untouched.

    Slots are created causally, when their id is first seen (``slots.Slots``): surprise at
    frame t depends on the frames, masks and camera poses up to t only (docs/architecture.md §7).

    ``surprise`` chooses what the dynamics predict and how code-space surprise is scored:

    - ``squared_error`` (the package's first choice): each slot's next code; trained by, and
      surprised by, the squared error between the code predicted from frames < t and the code
      perceived at t, summed over the slots seen by t. A hidden object's code is that of its
      empty mask.
    - ``likelihood`` (visibility-aware): each known slot's visibility at t (a Bernoulli) and,
      where seen, its code (a Gaussian with learned spread, at least ``min_code_std``); a
      hidden slot is rolled forward from its own prediction, without a target; a context over
      the known slots predicts whether a new object appears and its code
      (``SlotDynamics.rollout``). Trained by the negative log-likelihood of the frames;
      surprised by its rectified excess (``code_likelihood``), as the positive control is.

    ``surprise_space: pixels`` scores instead the squared pixel error between the observed
    frame and the frame composed of the decoded predicted codes (PLATO-style; with
    ``likelihood`` each slot weighed by its predicted visibility). Frame 0 scores 0. What
    PLATO's paper says of its surprise: docs/study/object_centric_surprise.md.

    Args:
        image_size: (H, W) of the frames, divisible by ``2 ** len(encoder_channels)``.
        num_slots: object slots (besides the background slot); a video with more object ids
            is refused.
        code_size: size of an object's code.
        encoder_channels: channels of the perception encoder's stride-2 convolutions.
        variational: VAE perception (KL weighted by ``kl_weight``) or a plain autoencoder.
        kl_weight: weight of the codes' KL to N(0, I) (a beta-VAE's beta).
        mask_loss_weight: weight of the cross-entropy between the composition weights and the
            true slot masks (the masks are given, so perception learns to segment by them).
        state_size, relation_sizes, node_sizes, relation_size: slotted LSTM state and the
            interaction network's MLPs (see ``SlotDynamics``).
        use_camera: the dynamics see the camera pose of the predicted frame (batch ``camera``).
        perception_steps: global steps of the perception stage; the dynamics train after it.
        perception_frames: frames per clip, drawn at random, that the perception stage trains
            on (perception sees single frames, so a few per clip suffice and cost a fraction
            of all); None trains on all.
        surprise: ``squared_error`` or ``likelihood`` (above).
        surprise_space: ``codes`` or ``pixels`` (above); it changes no parameter and no
            training, so a checkpoint may be tested with either (``EVALUATION_ONLY``).
        min_code_std: floor of the predicted codes' standard deviations (``likelihood``).
        code_loss_weight: weight of the code terms (``code``, ``newcomer_code``) in the
            ``likelihood`` dynamics' training loss (surprise is unweighted); None: 1 / the code
            size, the mean over a code's dimensions, so a code weighs about as much as a
            visibility bit. Summed over its dimensions, the code's gradient drowns the
            visibility's in the shared recurrent state: on scripted occlusion clips
            (tests/model/object_centric/test_visibility_aware.py), a hidden ball was expected back with p = 0.59 at
            weight 1 and 0.80 at 0.1 after the same 600 training steps.
        object_free: the twin without objects: a single slot whose code is of the whole frame
            (mask all ones, no masks needed, no interactions).
        object_free_code_size: the twin's code size; None sizes it so its parameter count is
            closest to the object-centric model's at the same arguments.
        max_mask_jump: the largest move of an object's mask centroid between consecutive frames,
            as a fraction of the frame diagonal, before a video is refused as having ids that
            change objects (``slots.refuse_jumps``; our scenes move at most 0.34); None: no check.
        learning_rate: Adam.
        channels_last: NHWC convolutions.
        training_frames: frames per training clip, recorded from the training batches.
    """

    ARCHITECTURE = ARCHITECTURE
    TRAINING_ONLY = ("learning_rate", "perception_steps", "code_loss_weight")
    # Not ``surprise``: it chooses the training loss, and the likelihood's visibility and spread
    # heads exist only in a model trained with it.
    EVALUATION_ONLY = ("surprise_space",)
    SURPRISE = SURPRISES[("squared_error", "codes")]

    def __init__(
        self,
        image_size: tuple[int, int] = (specs.HEIGHT, specs.WIDTH),
        num_slots: int = 8,
        code_size: int = 32,
        encoder_channels: Sequence[int] = (32, 32, 64, 64),
        variational: bool = True,
        kl_weight: float = 1.0,
        mask_loss_weight: float = 1.0,
        state_size: int = 128,
        relation_sizes: Sequence[int] = (128,),
        node_sizes: Sequence[int] = (128,),
        relation_size: int = 128,
        use_camera: bool = True,
        perception_steps: int = 1000,
        perception_frames: int | None = 4,
        surprise: str = "squared_error",
        surprise_space: str = "codes",
        min_code_std: float = 0.05,
        code_loss_weight: float | None = None,
        object_free: bool = False,
        object_free_code_size: int | None = None,
        max_mask_jump: float | None = MAX_MASK_JUMP,
        learning_rate: float = 1e-3,
        channels_last: bool = True,
        training_frames: int | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if num_slots < 1 or code_size < 1:
            raise ValueError(f"num_slots and code_size must be >= 1, got {num_slots}, {code_size}")
        if perception_frames is not None and perception_frames < 1:
            raise ValueError(f"perception_frames must be >= 1 or None, got {perception_frames}")
        if max_mask_jump is not None and max_mask_jump <= 0:
            raise ValueError(f"max_mask_jump must be > 0 or None (no check), got {max_mask_jump}")
        if perception_steps < 0 or learning_rate <= 0:
            raise ValueError(
                f"perception_steps must be >= 0 and learning_rate > 0, got "
                f"{perception_steps}, {learning_rate}"
            )
        if (surprise, surprise_space) not in SURPRISES:
            raise ValueError(
                f"surprise must be 'squared_error' or 'likelihood' and "
                f"surprise_space 'codes' or 'pixels', got {surprise!r} and "
                f"{surprise_space!r}"
            )
        if min_code_std <= 0 or (code_loss_weight is not None and code_loss_weight <= 0):
            raise ValueError(
                f"min_code_std must be > 0 and code_loss_weight > 0 or None, got "
                f"{min_code_std}, {code_loss_weight}"
            )
        #: What a frame's surprise is, for reports.
        self.SURPRISE = SURPRISES[(surprise, surprise_space)]
        self.image_size = (int(image_size[0]), int(image_size[1]))
        if not object_free:
            self.code_size = code_size
        elif object_free_code_size is None:
            self.code_size = matching_code_size(self.hparams)
        else:
            self.code_size = object_free_code_size
        self.perception, self.dynamics = build_networks(self.hparams, self.code_size)

    # ----------------------------------------------------------------------------- slots
    def slots(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None,
        seeds: torch.Tensor | None = None,
        consecutive: bool = True,
    ) -> Slots:
        """The slots of uint8 videos [B, T, H, W, 3] (see ``slots.object_slots``; frames not
        ``consecutive`` are a sample of a clip's frames, where ids may move far between two)."""
        if self.hparams["object_free"]:
            return whole_frame_slot(frames.to(self.device))
        mask = require_mask(mask, frames, seeds).to(self.device)
        max_jump = self.hparams["max_mask_jump"] if consecutive else None
        return object_slots(mask, self.hparams["num_slots"], seeds, max_jump)

    def perceive(self, x: torch.Tensor, slots: Slots) -> tuple[torch.Tensor, torch.Tensor]:
        """Model input [B, T, 3, H, W] -> code mean and log-std [B, T, S, C]."""
        batch, steps = x.shape[:2]
        mean, log_std = self.perception.encode(x.flatten(0, 1), slots.masks.flatten(0, 1))
        return mean.unflatten(0, (batch, steps)), log_std.unflatten(0, (batch, steps))  # type: ignore[no-untyped-call]  # Tensor.unflatten: unannotated in torch

    def render(
        self, codes: torch.Tensor, seen: torch.Tensor, log_visibility: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Codes [B, T, S, C] -> frames [B, T, 3, H, W] composed of the slots seen by each
        frame (``seen`` [B, T, S]) and log composition weights [B, T, S, H, W]; a slot's
        ``log_visibility`` [B, T, S], if given, is added to its mask logits (a slot expected
        hidden weighs nothing)."""
        batch, steps, slots = codes.shape[:3]
        rgb, logits = self.perception.decode(codes.flatten(0, 1))
        if log_visibility is not None:
            logits = logits + log_visibility.flatten(0, 1)[..., None, None]
        frame, log_weights = compose(rgb, logits, seen.flatten(0, 1))
        return (
            frame.view(batch, steps, *frame.shape[1:]),
            log_weights.view(batch, steps, slots, *log_weights.shape[2:]),
        )

    @property
    def visibility_aware(self) -> bool:
        """Whether the dynamics predict visibility and spread (``surprise: likelihood``)."""
        surprise: str = self.hparams["surprise"]
        return surprise == "likelihood"

    def _dynamics(
        self, codes: torch.Tensor, slots: Slots, camera: torch.Tensor | None
    ) -> DynamicsOutputs:
        """The dynamics over perceived ``codes``: ``predicted`` [B, T, S, C] (index t is the
        code expected at t + 1) and, when visibility-aware, ``rollout``'s distributions, the
        slots' ``visible`` [B, T, S] and the likelihood ``terms`` of frames 1..T-1."""
        if not self.visibility_aware:
            return {"predicted": self.dynamics(codes, slots.seen, camera)}
        visible = slots.masks.flatten(-2).sum(-1) > 0
        prediction = self.dynamics.rollout(codes, slots.seen, visible, camera)
        terms = code_likelihood.frame_terms(prediction, codes, slots.seen, visible)
        return {
            "predicted": prediction["mean"],
            "prediction": prediction,
            "visible": visible,
            "terms": terms,
        }

    def _predict(
        self, frames: torch.Tensor, mask: torch.Tensor | None, camera: torch.Tensor | None
    ) -> PassOutputs:
        """Deterministic pass: perceived codes, predicted codes aligned with them (index t is
        the code expected at t from frames < t; index 0 is the perceived code), the slots
        each frame is composed of (``present``; visibility-aware: those known before it) with
        their ``log_visibility`` (None: all weigh alike) and ``_dynamics``' outputs."""
        x = self._model_input(frames, self.image_size)
        slots = self.slots(frames, mask)
        codes, _ = self.perceive(x, slots)
        camera = camera.to(self.device) if camera is not None else None
        out = self._dynamics(codes, slots, camera)
        aligned = torch.cat([codes[:, :1], out["predicted"][:, :-1]], dim=1)
        present, log_visibility = slots.seen, None
        if self.visibility_aware:
            present = torch.cat([slots.seen[:, :1], slots.seen[:, :-1]], dim=1)
            logits = out["prediction"]["seen_logit"][:, :-1]
            log_visibility = F.pad(F.logsigmoid(logits), (0, 0, 1, 0))  # frame 0: as seen
        return {
            **out,
            "x": x,
            "codes": codes,
            "predicted": aligned,
            "seen": slots.seen,
            "present": present,
            "log_visibility": log_visibility,
        }

    # ----------------------------------------------------------------------------- training
    @property
    def perception_stage(self) -> bool:
        """Whether training is in its first stage (perception only)."""
        steps: int = self.hparams["perception_steps"]
        return self.global_step < steps

    def perception_terms(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """Perception loss per clip (mean over the batch), on ``perception_frames`` of its
        frames: reconstruction = sum over frames and pixels of the squared error of the
        composed frame; mask = cross-entropy of the composition weights against the true slot
        masks; kl = kl_weight * KL of the seen slots' codes to N(0, I) (VAE only)."""
        frames, mask = self._frames_of(batch), video_inputs(batch).get("mask")
        seeds = _seeds(batch)
        chosen = self.hparams["perception_frames"]
        sampled = chosen is not None and chosen < frames.shape[1]
        if sampled:
            self.slots(frames, mask, seeds)  # refuses bad masks on the whole, consecutive clip
            steps = torch.randperm(frames.shape[1])[:chosen].sort().values
            frames, mask = frames[:, steps], (mask[:, steps] if mask is not None else None)
        x = self._model_input(frames, self.image_size)
        slots = self.slots(frames, mask, seeds, consecutive=not sampled)
        return autoencoder_terms(
            self.perception, x, slots, self.hparams["kl_weight"], self.hparams["mask_loss_weight"]
        )

    def dynamics_terms(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """Dynamics loss per clip (mean over the batch), against the frozen perception's codes
        of frames 1..T-1: the squared error of the predicted codes, summed over the slots seen
        by the predicted frame; visibility-aware, the negative log-likelihood of each term of
        ``code_likelihood.TERMS``, summed, the code terms weighed by ``code_loss_weight``."""
        frames = self._frames_of(batch)
        inputs = video_inputs(batch)
        x = self._model_input(frames, self.image_size)
        slots = self.slots(frames, inputs.get("mask"), _seeds(batch))
        with torch.no_grad():
            codes, _ = self.perceive(x, slots)
        camera = inputs["camera"].to(self.device) if "camera" in inputs else None
        out = self._dynamics(codes, slots, camera)
        clips = x.shape[0]
        if self.visibility_aware:
            terms = {
                name: nll.sum() / clips
                for name, nll in code_likelihood.negative_log_likelihood(out["terms"]).items()
            }
            weight = self.hparams["code_loss_weight"] or 1 / self.code_size
            loss = sum(
                value * (weight if name in code_likelihood.CODE_TERMS else 1.0)
                for name, value in terms.items()
            )
            assert isinstance(loss, torch.Tensor)  # a sum of the terms, each a tensor
            return {"loss": loss, **terms}
        error = (out["predicted"][:, :-1] - codes[:, 1:]).pow(2).sum(-1) * slots.seen[:, 1:]
        prediction = error.sum() / clips
        return {"loss": prediction, "prediction": prediction}

    def training_step(self, batch: TensorDictBase, batch_idx: int) -> torch.Tensor:
        stage = "perception" if self.perception_stage else "dynamics"
        if stage == "perception":
            terms = self.perception_terms(batch)
        else:
            self.perception.eval()
            terms = self.dynamics_terms(batch)
        self._check_finite(terms)
        batch_size = self._frames_of(batch).shape[0]
        self.log("train/loss", terms["loss"], prog_bar=True, batch_size=batch_size)
        for name, value in terms.items():
            if name != "loss":
                self.log(f"train/{stage}/{name}", value, batch_size=batch_size)
        return terms["loss"]

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(self.parameters(), lr=self.hparams["learning_rate"])

    # ----------------------------------------------------------------------------- protocol
    def probe_step(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """The shared probe step, after refusing, naming the pair's seed, a probe video
        without a mask or with more objects than slots."""
        if not self.hparams["object_free"]:
            for side in ("consistent", "inconsistent"):
                frames, seeds = batch[side, "frames"], _seeds(batch)
                mask = require_mask(video_inputs(batch, side).get("mask"), frames, seeds)
                object_slots(mask, self.hparams["num_slots"], seeds)
        return super().probe_step(batch)

    def inputs_read(self) -> frozenset[str]:
        """Frames and the object-id masks its slots come from."""
        return frozenset({"mask"})

    @torch.no_grad()
    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """Per-frame surprise [B, T] (float32), see the class docstring."""
        out = self._predict(frames, mask, camera)
        if self.hparams["surprise_space"] == "pixels":
            expected, _ = self.render(out["predicted"], out["present"], out["log_visibility"])
            surprise = (expected - out["x"]).pow(2).sum(dim=(2, 3, 4))
        elif self.visibility_aware:
            surprise = F.pad(code_likelihood.excess_surprisal(out["terms"]), (1, 0))
        else:
            error = (out["predicted"] - out["codes"]).pow(2).sum(-1) * out["seen"]
            surprise = error.sum(-1)
        surprise[:, 0] = 0.0
        return surprise.float()

    @torch.no_grad()
    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """The decoded, composed predicted codes [B, T, 3, H, W] in [0, 1] (frame 0: the
        reconstruction of the first frame; visibility-aware, each slot weighed by its
        predicted visibility)."""
        out = self._predict(frames, mask, camera)
        return self.render(out["predicted"], out["present"], out["log_visibility"])[0]

    @torch.no_grad()
    def trajectories(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> dict[str, torch.Tensor]:
        """``codes`` (perceived) and ``predicted`` [B, T, S * C], the slots' codes flattened
        per frame (slots not yet seen and padding slots zeroed)."""
        out = self._predict(frames, mask, camera)
        keep = out["seen"][..., None].float()
        return {
            "codes": (out["codes"] * keep).flatten(2),
            "predicted": (out["predicted"] * keep).flatten(2),
        }


def _seeds(batch: TensorDictBase) -> torch.Tensor | None:
    """The batch's seeds, which errors name, when it has them."""
    return batch["seed"] if "seed" in batch.keys() else None

"""The positive control: an object-state learner with perfect perception. It reads what a
perfect 3D perception system would hand to physics (per frame, the states of the objects visible
at that frame, ``specs.objects_spec``, hidden ones masked out, and the camera pose), learns their
dynamics from the training clips, tracks hidden objects forward, and is surprised by the negative
log-likelihood of what is then seen. If it cannot show VOE on a concept, the stimuli are wrong."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, cast

import torch
from tensordict import TensorDictBase
from torch import nn

from voe_lightning import specs
from voe_lightning.model import optimization
from voe_lightning.model.base import SurpriseModel, video_inputs
from voe_lightning.model.dynamics import CAMERA_FEATURES, mlp
from voe_lightning.model.likelihood import rectified_excess
from voe_lightning.model.object_state import rgbd
from voe_lightning.model.object_state.arguments import ARCHITECTURE, check_arguments
from voe_lightning.model.object_state.geometry import VIEW, draw_ellipses
from voe_lightning.model.object_state.masks import (
    MASKS,
    observe_masks,
    observe_measured,
    paint_boxes,
)
from voe_lightning.model.object_state.pairs import PairNetwork, pair_feature_size
from voe_lightning.model.object_state.pixels import (
    background_codes,
    code_layout,
    encoder_terms,
    object_encoder,
    observe_pixels,
    paint_codes,
)
from voe_lightning.model.object_state.rollout import FLOOR_FEATURES, SlotRollout, slot_feature_size
from voe_lightning.model.object_state.state import (
    SHAPES,
    SLOT_TERMS,
    STATES,
    Observations,
    StateLayout,
    by_object_count,
    observe,
    withheld_spans,
)

if TYPE_CHECKING:
    from lightning.pytorch.utilities.types import OptimizerConfig, OptimizerLRSchedulerConfig


#: The state layouts of the perceptions that name one (a learned code's is ``code_layout``).
LAYOUTS = {"states": STATES, "masks": MASKS, "rgbd": rgbd.RGBD}
#: What each perception's surprise reads of a video (``inputs_read``); the others, the mask.
READS = {"states": frozenset({"objects"}), "rgbd": frozenset({"mask", "depth"})}


def layout_of(perception: str, code_size: int) -> StateLayout:
    """What the learner perceives (``perception``): its state layout."""
    return LAYOUTS.get(perception) or code_layout(code_size)


class ObjectStateModel(SlotRollout, SurpriseModel):
    """Slot dynamics over perceived object states: with no prior, the package's learned result
    (``configs/learned_states.yaml``); its defaults are the positive control
    (``configs/object_state.yaml``; how each part came to be: docs/study/positive_control.md).

    Each mask id is a slot, created when the id is first seen. Per frame t, from the slots
    after frame t-1, the model predicts every known slot's state at t (a mixture of Gaussians,
    ``_mixture``: each mean the belief moved on by inertia, ``inertial_move``, plus a learned
    change, never below the floor), its shape (a categorical) and whether it is seen (a
    Bernoulli, ``_visibility_logit``: learned from the slot's memory, plus the sight lines to
    the boxes at the predicted states; or, ``visibility_from: states``, learned from the
    predicted states alone);
    a context over the known slots predicts whether a new object appears. The most probable
    Gaussian is the predicted state, which a hidden slot's belief follows. Then the frame's observations update the beliefs and,
    through an interaction network over slot pairs, a GRU per slot. Training minimises the
    negative log-likelihood (NLL) of the training clips' frames, some seen objects withheld
    for a few frames so that tracking a hidden object learns from targets. Surprise at frame t
    is the rectified excess of each term's NLL over its entropy (``_per_frame``).

    Given, not learned (the one prior, kept by measurement): the landing Gaussian, laid down
    onto a known object's top (``landing_component``, ``pivot_landing``), with which every
    quadruplet half stands on its own on validation (docs/study/learned_physics.md); the
    stopping Gaussian and the control's six priors (carrying, slowing, falling lands, the
    fall's gain, holding still, shared identity), each added alone, added no verdict and no
    half standing alone, and were deleted. The
    package's learned result (``configs/learned_states.yaml`` with its overlays) turns it off. Given to every configuration, and each removable to measure what it
    costs: the sight lines of the visibility (``sight_lines``), the floor under every mean
    (``floor``), the inertial baseline (``inertia``) and the image-plane projection the
    networks read (``projection``). Kept by measurement (docs/study/learned_physics.md,
    2026-12-01): removed one after another, each step passes 3 of 5 concepts on a fresh set
    against 5 of 5 with all four, containment failing at every step; with all four removed and
    the visibility learned from the states (``configs/oracle_states_1000_steps.yaml``), 4 of 5
    at three seeds (2026-12-05), object persistence failing, without learning how things move;
    trained five times as long, unclipped (``configs/oracle_states_batch32.yaml``), it
    learns motion and occlusion and passes 5, 4 and 5 of 5; at a large batch
    (``configs/oracle_states.yaml``, the ceiling) 5, 5 and 5 with an empty untrained null, and
    with its heads started at zero (``configs/oracle_states_15min.yaml``) 4, 4 and 4, its
    null empty by construction. Its one structural given, how
    p(seen) is composed (in view, and covered by no other known slot: a product), changed no
    verdict against an additive composition on validation at 1,000 steps and was not measured
    trained long. Never removable: one slot per
    tracker id, the states of the objects while seen, the camera pose, the mixture's bound
    on a frame's move (``MAX_MOVE``), and the move between a slot's last two states, which its
    GRU reads whether or not ``inertia`` is on. With ``perception: states`` those states are an
    oracle's (issue 70): every object's whole 3D box while any of it is seen, occluders' too,
    one slot per id that never dies, so identity through occlusion and permanence are given;
    it is the ceiling a camera learner is read against, not a learner from vision.

    With ``perception: masks`` (the mask rung, ``configs/learned_masks.yaml``) it reads no 3D
    state: per mask id, the image-plane centroid, half-extents, area and mean colour of its
    pixels in the record's ``mask`` and ``frames`` (``masks.observe_masks``), which it predicts
    as it predicts a 3D state; no 3D geometry or prior applies to them, and ``projection``
    reads the boxes the pixels span, as seen or believed (``masks.seen_box``). Its two givens,
    the inertial baseline and the boxes' overlaps, changed no verdict on validation (2 of 5
    with and without each, docs/study/learned_physics.md); the published run has both, and
    which of them to drop waits on a mask rung that passes more.

    With ``perception: rgbd`` (the RGB-D rung, ``configs/rgbd_15min.yaml``) it is given what a
    depth camera and a tracker give: per mask id and frame, the mask rung's 2D measures of its
    visible pixels plus their mean depth along the view axis, from the record's ``mask``,
    ``frames`` and ``depth`` (``rgbd.observe_rgbd``); no 3D box, no shape label, no oracle, and
    it never reads ``objects``. Its state (``rgbd.RGBD``) holds the mean depth in its position,
    so its velocity holds the change in depth, and the largest size each id has shown so far
    (``rgbd.largest_shown``), so a block's height outlasts the screen that hides most of it;
    ``projection`` reads the pixels' boxes. ``configs/rgbd_15min.yaml`` gives it the inertial
    baseline, kept by measurement (validation: 3, 3, 3 of 5 with it, 2, 3, 2 without).

    With ``perception: pixels`` (the pixel rung, ``configs/learned_pixels.yaml``) no feature
    is hand-written either: an object's state is the code a learned encoder gives its pixels
    (``pixels.observe_pixels``). The encoder, PLATO's object autoencoder, trains alone for the
    first ``perception_steps`` steps, then is frozen while the rest learns over its codes.

    Args:
        perception: ``"states"`` (perfect 3D perception, ``specs.objects_spec``),
            ``"masks"`` (what the mask and frames show of each id, no 3D state), ``"rgbd"``
            (the masks' measures of each id plus the mean depth of its visible pixels and the
            largest size it has shown, ``specs.depth_spec``: no 3D box, no shape label, no
            oracle; never reads ``objects``) or ``"pixels"`` (a learned code of each id's pixels).
        hidden_size: recurrent state per slot and width of the MLPs.
        message_size: size of the summed pair messages.
        use_camera: the core and visibility read the camera pose (else a fixed default pose).
        min_std: floor of the predicted standard deviations (a perfect perception's precision).
        components: Gaussians in the mixture over each slot's next state (1: one Gaussian).
        landing_component: the last Gaussian lays the object down, size and colour kept.
        pivot_landing: it lays it down turned about its box's lowest corner onto a known
            object's top (``pivoted_down``), else flat on the floor (``lying_on_floor``).
        landing_change: the landing Gaussian takes the learned change too (false: inertia only).
        sight_lines: the visibility logit adds sight lines from the camera to every known
            object's box at its predicted state (``seen_by_geometry``; false: learned alone).
        floor: no Gaussian's mean is below the floor (``on_or_above_floor``).
        inertia: each mean starts from the belief moved on by the last move
            (``inertial_move``; false: the network predicts the whole move).
        projection: the networks read each object's camera coordinates and image-plane box
            (``view``) and the pairs' image overlaps (false: only the states and the pose).
        visibility_from: what the learned p(seen) reads (``_visibility_logit``): ``"memory"``,
            the slot's recurrent state and messages from the others; ``"states"``, only the
            predicted states and the pose, composed as p(in view) times the chance that no
            other known object covers it, each a network (no memory: what is seen follows
            from where things are, as with the sight lines, but learned).
        withhold: share of each training clip's objects withheld for a span of frames
            (``withheld_spans``; 0: never).
        withhold_frames: the longest withheld span, in frames.
        hard_assignment: training scores a seen state by its best-explaining Gaussian alone
            (surprise and validation use the whole mixture).
        group_by_objects: training rolls a batch's clips out in groups of equal object count,
            each with only as many slots as its clips show (``by_object_count``): the same loss
            with no slot pair run for an empty slot, faster at large batches (hundreds of
            clips), slower at small ones, where each group's steps cost more than padding.
        zero_heads: every network's last layer that predicts (a state's change and spread,
            the Gaussians' weights, the shape, whether it is seen, any newcomer) starts at zero
            (``_zero_heads``): untrained, every draw is the same learner, which predicts no
            move and even odds, so an untrained null finds no chance bias of a draw (drawn, 3
            of 10 untrained copies passed object persistence). Gaussians that start alike may
            stay alike (trained long, two of four were still one).
        learning_rate: Adam's (peak) learning rate.
        lr_schedule: ``"constant"`` or ``"cosine"`` (decays to 0 at ``trainer.max_steps``).
        training_frames: frames per training clip, recorded from the training batches.
        code_size: an object's code, perceived by pixels.
        frame_size: (H, W) of the frames, perceived by pixels (divisible by 16; None: the
            generator's, ``specs.HEIGHT`` x ``specs.WIDTH``).
        perception_steps: perceived by pixels, the first training steps, which train the
            encoder alone (then frozen).
        perception_frames: random frames per clip in those steps.
    """

    ARCHITECTURE = ARCHITECTURE
    TRAINING_ONLY = (
        "learning_rate",
        "lr_schedule",
        "withhold",
        "withhold_frames",
        "hard_assignment",
        "group_by_objects",
        "zero_heads",
        "perception_steps",
        "perception_frames",
    )
    SURPRISE = (
        "the rectified excess surprisal of the seen object states (each term's negative "
        "log-likelihood less its entropy, where positive: the visibility, state and shape "
        "of every known object, and any newcomer's appearance)"
    )

    def __init__(
        self,
        perception: str = "states",
        hidden_size: int = 128,
        message_size: int = 64,
        use_camera: bool = True,
        min_std: float = 0.01,
        components: int = 4,
        landing_component: bool = True,
        pivot_landing: bool = True,
        landing_change: bool = True,
        sight_lines: bool = True,
        floor: bool = True,
        inertia: bool = True,
        projection: bool = True,
        visibility_from: str = "memory",
        withhold: float = 0.5,
        withhold_frames: int = 8,
        hard_assignment: bool = True,
        group_by_objects: bool = False,
        zero_heads: bool = False,
        learning_rate: float = 1e-3,
        lr_schedule: str = "cosine",
        training_frames: int | None = None,
        code_size: int = 16,
        frame_size: tuple[int, int] | None = None,
        perception_steps: int = 500,
        perception_frames: int = 4,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        check_arguments(self.hparams)
        hidden, message = hidden_size, message_size
        self.layout = layout = layout_of(perception, code_size)
        if perception == "pixels":
            self.encoder = object_encoder(code_size, self.frame_size)
        pairs = pair_feature_size(layout)
        self.message = PairNetwork(hidden, hidden, pairs, hidden, message)
        self.update = nn.GRUCell(slot_feature_size(layout) + message + CAMERA_FEATURES, hidden)
        floor_features = FLOOR_FEATURES if landing_component else 0
        self.dynamics = mlp(
            [
                hidden + message + CAMERA_FEATURES + floor_features,
                hidden,
                hidden,
                self._dynamics_outputs(components, layout.size),
            ]
        )
        if visibility_from == "states":  # p(seen) composed from the predicted states and pose
            self.in_view = mlp([layout.size + VIEW + CAMERA_FEATURES, hidden, 1])
            self.cover = mlp([pairs + layout.size + VIEW + CAMERA_FEATURES, hidden, 1])
        else:
            self.occlusion = PairNetwork(hidden, 0, pairs, hidden, message)
            self.visibility = mlp(
                [hidden + message + VIEW + layout.extent_size + CAMERA_FEATURES, hidden, 1]
            )
        if sight_lines:
            #: How much the visibility logit starts from geometry (``seen_by_geometry``); learned.
            self.geometry_weight = nn.Parameter(torch.ones(()))
        self.appearance = mlp([hidden + CAMERA_FEATURES, hidden, 1 + 2 * layout.size + SHAPES])
        self.log_min_std = math.log(min_std)
        if zero_heads:
            self._zero_heads()

    def _zero_heads(self) -> None:
        """Start every prediction at nothing (``zero_heads``): no change of state, a standard
        deviation near 1, even weights, uniform shapes, even odds of being seen and of a
        newcomer: the same function whatever the draw."""
        heads = [self.dynamics, self.appearance]
        heads += (
            [self.in_view, self.cover]
            if self.hparams["visibility_from"] == "states"
            else [self.visibility]
        )
        for head in heads:
            last = cast(nn.Linear, head[-1])  # mlp's, which nn.Sequential types as any module
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)

    @staticmethod
    def _dynamics_outputs(components: int, state_size: int) -> int:
        """Per slot: each component's change and log-std, the components' logits (none for
        one component) and the shape's logits."""
        return components * 2 * state_size + (components if components > 1 else 0) + SHAPES

    # ----------------------------------------------------------------------------- inputs
    def _inputs(
        self,
        frames: torch.Tensor | None,
        objects: TensorDictBase | None = None,
        camera: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
        mask_features: TensorDictBase | None = None,
        depth: torch.Tensor | None = None,
    ) -> Observations:
        """The batch's ``Observations`` as ``perception`` reads them, at a fixed pose without
        a camera or ``use_camera``. Perceiving states, it needs no ``frames`` (a training batch
        of ``train_fields: [objects, camera]`` holds none); perceiving masks (or rgbd), a
        training batch of ``train_fields: [mask_features, camera]`` holds each clip's
        ``masks.per_id`` measures (rgbd: with the ``depth``), made once when the clips were
        loaded, and no mask or frame."""
        perception = self.hparams["perception"]
        if perception in ("masks", "rgbd") and mask_features is not None:
            pose = self._pose(mask_features["pixels"].shape[:2], camera).to(self.device)
            observe_held = observe_measured if perception == "masks" else rgbd.observe_rgbd_measured
            return observe_held(mask_features.to(self.device), pose)
        if perception in ("masks", "rgbd", "pixels"):
            if mask is None or frames is None:
                missing = "mask" if mask is None else "frames"
                raise ValueError(
                    f"the object-state model with perception: {self.hparams['perception']} reads "
                    "each video's object-id mask and frames, but a batch came without batch "
                    f"key '{missing}'"
                )
            mask, frames = mask.to(self.device), frames.to(self.device)
            camera = self._pose(frames.shape[:2], camera).to(self.device)
            if perception == "masks":
                return observe_masks(mask, frames, camera)
            if perception == "rgbd":  # refused without a depth
                return rgbd.observe_rgbd(mask, frames, depth, camera)
            frames = self._checked_frames(frames, self.frame_size)
            with torch.no_grad():  # the encoder learns only from its own loss
                return observe_pixels(self.encoder, mask, frames, camera)
        if objects is None:
            raise ValueError(
                "the object-state model (the positive control) reads each video's object "
                "states (batch key 'objects', specs.objects_spec), but a batch came without "
                "them; use the package's generated records (GENERATOR_VERSION 3 or later)"
            )
        camera = self._pose(objects["position"].shape[:2], camera)
        return observe(objects.to(self.device), camera.to(self.device))

    def _pose(self, clips: tuple[int, ...], camera: torch.Tensor | None) -> torch.Tensor:
        """The camera poses [B, T, 6] the model reads: the batch's, or a fixed default pose
        without a camera or ``use_camera``."""
        if camera is not None and self.hparams["use_camera"]:
            return camera
        pose = torch.tensor([0.0, 0.0, 0.4, 4.0, 90.0, -20.0], device=self.device)
        return pose.expand(*clips, 6)

    def _per_frame(self, out: dict[str, torch.Tensor]) -> torch.Tensor:
        """Each frame's surprise [B, T]: the positive part of the excess surprisal of each
        term of each slot (its negative log-likelihood minus its expectation under the
        model's own prediction, the entropy), summed. Only what is less likely than expected
        counts: a density's raw NLL rewards every visible object with a negative term (about
        -40 nats a frame at 1 cm precision), and so does its excess, if less, where the model
        predicts better than its floor of precision; either way the video showing more would
        read as less surprising, whatever its physics."""

        def excess(name: str) -> torch.Tensor:
            return rectified_excess(out[name], out[f"{name}_entropy"])

        return sum(excess(name).sum(-1) for name in SLOT_TERMS) + excess("appear")

    # ----------------------------------------------------------------------------- training
    def training_step(self, batch: TensorDictBase, batch_idx: int) -> torch.Tensor:
        inputs = video_inputs(batch, read=self.inputs_read())
        frames = batch["frames"] if "frames" in batch.keys() else None
        if self.perception_stage:
            return self._encoder_step(frames, inputs.get("mask"))
        features = batch["mask_features"] if "mask_features" in batch.keys() else None
        observations = self._inputs(frames, mask_features=features, **inputs)
        clips = observations.visible.shape[0]
        names = SLOT_TERMS + ("appear",)
        terms: dict[str, torch.Tensor] = {}
        groups = (
            by_object_count(observations) if self.hparams["group_by_objects"] else [observations]
        )
        for group in groups:
            withheld = withheld_spans(
                group.visible.shape,
                self.hparams["withhold"],
                self.hparams["withhold_frames"],
                group.visible.device,
            )
            out = self.rollout(group, withheld, keys=names)
            for name in names:  # the negative log-likelihood of the clips
                terms[name] = terms.get(name, 0.0) + out[name].sum() / clips
        loss = sum(terms.values())
        assert isinstance(loss, torch.Tensor)  # a sum of tensors: there is a group at least
        terms["loss"] = loss
        self._check_finite(terms)
        self.log("train/loss", terms["loss"], prog_bar=True, batch_size=clips)
        for name, value in terms.items():
            if name != "loss":
                self.log(f"train/{name}", value, batch_size=clips)
        return terms["loss"]

    @property
    def frame_size(self) -> tuple[int, int]:
        """(H, W) of the frames the pixel encoder reads."""
        height, width = self.hparams["frame_size"] or (specs.HEIGHT, specs.WIDTH)
        return int(height), int(width)

    @property
    def perception_stage(self) -> bool:
        """Whether training is in its first stage: the pixel encoder alone."""
        pixels: bool = self.hparams["perception"] == "pixels"
        return pixels and self.global_step < self.hparams["perception_steps"]

    def _encoder_step(self, frames: torch.Tensor | None, mask: torch.Tensor | None) -> torch.Tensor:
        """A step of the pixel encoder alone (``pixels.encoder_terms``)."""
        if frames is None or mask is None:
            raise ValueError(
                "the object-state model with perception: pixels learns its encoder from each "
                "training clip's frames and object-id mask, but a batch came without them"
            )
        terms = encoder_terms(
            self.encoder,
            mask.to(self.device),
            self._checked_frames(frames, self.frame_size),
            self.hparams["perception_frames"],
        )
        self._check_finite(terms)
        for name, value in terms.items():
            self.log(f"train/encoder_{name}", value, prog_bar=name == "loss", batch_size=len(mask))
        return terms["loss"]

    def configure_optimizers(self) -> OptimizerConfig | OptimizerLRSchedulerConfig:
        return optimization.adam(
            self.parameters(),
            self.hparams["learning_rate"],
            self.hparams["lr_schedule"],
            getattr(self._trainer, "max_steps", None),
        )

    # ----------------------------------------------------------------------------- protocol
    def inputs_read(self) -> frozenset[str]:
        """What a camera gives (the mask; frames and camera always; rgbd's depth too, which
        only a model that reads it is given) for ``perception`` masks, rgbd or pixels, which
        never read the record's amodal ``objects``; those for states (``READS``)."""
        return READS.get(self.hparams["perception"], frozenset({"mask"}))

    @torch.no_grad()
    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
        depth: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Per-frame surprise [B, T] (float32): the NLL of what is seen (class docstring);
        rgbd alone reads ``depth`` [B, T, K, 3] (``specs.depth_spec``)."""
        out = self.rollout(self._inputs(frames, objects, camera, mask, depth=depth))
        return self._per_frame(out).float()

    @torch.no_grad()
    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
        depth: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """What the model expected [B, T, 3, H, W]: each known slot's expected state drawn as an
        ellipse of its colour where and as large as its box is seen, as opaque as the predicted
        probability that it is seen (frame 0: what is seen), nearer objects over farther;
        perceived by pixels, each expected code decoded over the frame before's background."""
        observations = self._inputs(frames, objects, camera, mask, depth=depth)
        out = self.rollout(observations)
        belief = torch.cat([out["belief"][:, :1], out["predicted"][:, 1:]], dim=1)
        opacity = torch.cat(
            [observations.visible[:, :1].float(), out["visible_probability"][:, 1:]], dim=1
        )
        if self.hparams["perception"] == "pixels":  # each belief decoded, over the last background
            assert mask is not None  # _inputs refused a video without one
            background = background_codes(
                self.encoder, mask.to(self.device), frames.to(self.device)
            )
            before = torch.cat([background[:, :1], background[:, :-1]], dim=1)
            return paint_codes(self.encoder, belief, opacity, before)
        height, width = frames.shape[2:4]
        if self.hparams["perception"] in ("masks", "rgbd"):  # an ellipse in its pixels' box
            return paint_boxes(belief, opacity, self.layout, (height, width))
        return draw_ellipses(belief, opacity, observations.camera, (height, width))

    @torch.no_grad()
    def trajectories(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
        depth: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """``slots`` [B, T, H]: the mean recurrent state of the known slots at each frame."""
        out = self.rollout(self._inputs(frames, objects, camera, mask, depth=depth))
        weight = out["known"].float()[..., None]
        return {"slots": (out["hidden"] * weight).sum(2) / weight.sum(2).clamp(min=1)}

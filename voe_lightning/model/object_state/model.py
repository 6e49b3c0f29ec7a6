"""The positive control: an object-state learner with perfect perception. It reads what a
perfect 3D perception system would hand to physics (per frame, the states of the objects visible
at that frame, ``specs.objects_spec``, hidden ones masked out, and the camera pose), learns their
dynamics from the training clips, tracks hidden objects forward, and is surprised by the negative
log-likelihood of what is then seen. If it cannot show VOE on a concept, the stimuli are wrong."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase
from torch import nn

from voe_lightning import specs
from voe_lightning.model import optimization
from voe_lightning.model.base import SurpriseModel, video_inputs
from voe_lightning.model.dynamics import CAMERA_FEATURES, camera_features, mlp
from voe_lightning.model.likelihood import (
    bernoulli_nll,
    categorical_nll,
    gaussian_nll,
    mixture_nll,
    rectified_excess,
)
from voe_lightning.model.object_state.geometry import (
    REST_TOLERANCE,
    VIEW,
    draw_ellipses,
    lowest_point,
    lying_on_floor,
    on_or_above_floor,
    pivoted_down,
    resting_on,
    seen_by_geometry,
    view,
)

#: The continuous state of an object that the model predicts: position (3), orientation (4),
#: size (3), colour (3). A sphere's orientation cannot be seen, so it reads as the identity.
STATE_SIZE = 13
#: Where each part lies in a state: position, orientation (w, x, y, z), size, colour; what an
#: object is (``IDENTITY``: size and colour) against where it is and how it is turned (``POSE``).
POSITION, ORIENTATION, SIZE, COLOR = slice(0, 3), slice(3, 7), slice(7, 10), slice(10, 13)
POSE, IDENTITY = slice(0, 7), slice(7, 13)
#: Where each part lies in a ``view``: camera coordinates, image-box centre and half-extents.
CAMERA_XYZ, BOX_CENTRE, BOX_HALF = slice(0, 3), slice(3, 5), slice(5, 7)
SHAPES = len(specs.OBJECT_SHAPES)
SPHERE = specs.OBJECT_SHAPES.index("sphere")
#: Per-slot features the recurrent core reads: the state, its shape (one-hot), its visible share,
#: its view, its velocity and whether it is seen.
FEATURES = STATE_SIZE + SHAPES + 1 + VIEW + 3 + 1
#: Pair features: the other object's position, camera coordinates and image-box centre relative
#: to this one's, both sizes, both image-box half-extents, how much of this one's image box the
#: other's covers (along right, up, and both), the other's orientation and shape.
PAIR_FEATURES = 3 + 3 + 2 + 3 + 3 + 2 + 2 + 3 + 4 + SHAPES
#: The largest move of a state in one frame interval, in each of the inertia and the learned
#: change (metres for positions; our fastest object, a falling block, moves 0.6 m a frame).
MAX_MOVE = 1.5
#: An object moves when it moved more than this many metres in its last frame interval.
MOVING = 0.02
#: The logit that takes a Gaussian out of the mixture (``falling_lands``): finite, so that its
#: share of the entropy is 0 * finite, not 0 * inf.
LEFT_OUT = -1.0e4
#: The per-slot terms of a frame's negative log-likelihood; ``appear`` is per frame.
SLOT_TERMS = ("visibility", "state", "shape", "newcomer_state", "newcomer_shape")

#: Constructor arguments that shape the parameters, or the priors they were trained with: a
#: checkpoint must agree on all of them.
ARCHITECTURE = (
    "hidden_size",
    "message_size",
    "use_camera",
    "components",
    "stop_component",
    "landing_component",
    "pivot_landing",
    "landing_change",
    "carry",
    "hold_still",
    "slowing",
    "falling_lands",
    "fall_gain",
    "shared_identity",
)
#: Per-slot inputs of the dynamics with ``landing_component``: how high the lowest point of the
#: object's box is above the floor at its belief and where its inertia would take it.
FLOOR_FEATURES = 2
#: What a carrier passes on (``carry``): nothing, or, to what rests on it, its whole move.
CARRIES = ("none", "support")


@dataclass
class Observations:
    """What perfect perception reports of a batch of videos, per video over the mask ids
    ``ids`` [B, S] it shows (``observe``): ``state`` [B, T, S, 13] and ``shape`` one-hot
    [B, T, S, 7] (zero where hidden), ``fraction`` [B, T, S] visible share of the frame,
    ``visible`` bool [B, T, S]; ``camera`` [B, T, 6] poses."""

    ids: torch.Tensor
    state: torch.Tensor
    shape: torch.Tensor
    fraction: torch.Tensor
    visible: torch.Tensor
    camera: torch.Tensor


def observe(objects: TensorDictBase, camera: torch.Tensor) -> Observations:
    """The visible objects' states of batched ``objects`` (``specs.objects_spec`` [B, T, K]):
    every state of an object is zeroed at the frames where it has no visible pixel, so nothing
    hidden reaches the model. Each video's slots are the mask ids it shows, in the order they
    are first seen (then by id), padded with ids it never shows: a slot that joins later takes
    a later place, and empty slots add exact zeros, so nothing before it changes."""
    seen = objects["visible_fraction"] > 0  # [B, T, K]
    steps, count = seen.shape[1:]
    first = torch.where(seen.any(1), seen.float().argmax(1), steps)  # [B, K]; T: never
    first[:, 0] = steps + 1  # the background is no object
    order = (first * count + torch.arange(count, device=seen.device)).argsort(dim=1)
    slots = int((first <= steps - 1).sum(1).max())
    ids = order[:, :slots]  # [B, S]
    picked = {
        name: value.gather(
            2,
            ids[:, None]
            .expand(-1, steps, -1)
            .reshape(*ids.shape[:1], steps, slots, *([1] * (value.dim() - 3)))
            .expand(-1, -1, -1, *value.shape[3:]),
        )
        for name, value in objects.items()
    }  # [B, T, S, ...]
    visible = picked["visible_fraction"] > 0
    label = picked["shape_label"].long()
    orientation = picked["orientation"].float()
    orientation = orientation * torch.where(orientation[..., :1] < 0, -1.0, 1.0)  # w >= 0
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], device=orientation.device)
    orientation = torch.where((label == SPHERE)[..., None], identity, orientation)
    state = torch.cat(
        [picked["position"].float(), orientation, picked["size"].float(), picked["color"].float()],
        dim=-1,
    )
    keep = visible[..., None].float()
    return Observations(
        ids=ids,
        state=state * keep,
        shape=F.one_hot(label, SHAPES).float() * keep,
        fraction=picked["visible_fraction"].float() * visible,
        visible=visible,
        camera=camera.float(),
    )


@dataclass
class Holding:
    """Which slots stay where they rest while unseen (``carry: support``, ``hold_still``):
    what each rests on, one-hot [B, S, S] (``resting_on``; zeros: the floor or nothing),
    whether it is held [B, S], and where, its belief moved by its support's predicted move
    [B, S, 13]."""

    rests: torch.Tensor
    holds: torch.Tensor
    state: torch.Tensor


@dataclass
class Slots:
    """The slots after a frame, each [B, S, ...]: ``hidden`` recurrent states, ``belief`` (the
    last state seen or, while hidden, predicted), ``shape`` one-hot, the last ``velocity`` and
    its change (``acceleration``), ``known`` (seen at some frame so far) and ``still`` (last
    seen in two frames running not moving across the floor)."""

    hidden: torch.Tensor
    belief: torch.Tensor
    shape: torch.Tensor
    velocity: torch.Tensor
    acceleration: torch.Tensor
    known: torch.Tensor
    still: torch.Tensor


@dataclass
class Mixture:
    """A mixture over each slot's next state: ``means`` and ``log_std`` [B, S, K, 13] and the
    components' ``logits`` [B, S, K] (None for one Gaussian)."""

    means: torch.Tensor
    log_std: torch.Tensor
    logits: torch.Tensor | None

    def most_probable(self) -> torch.Tensor:
        """Each slot's most probable component's mean [B, S, 13]."""
        top = (
            self.logits.argmax(-1)
            if self.logits is not None
            else self.means.new_zeros(self.means.shape[:2], dtype=torch.long)
        )
        return self.means.gather(2, top[..., None, None].expand(-1, -1, 1, STATE_SIZE))[:, :, 0]


def _check_arguments(h) -> None:
    """Refuse constructor arguments that make no model, naming the value and what is valid."""
    if h.hidden_size < 1 or h.message_size < 1:
        raise ValueError(
            f"hidden_size and message_size must be >= 1, got {h.hidden_size}, {h.message_size}"
        )
    if h.min_std <= 0 or h.learning_rate <= 0:
        raise ValueError(
            f"min_std and learning_rate must be > 0, got {h.min_std}, {h.learning_rate}"
        )
    if h.components < 1:
        raise ValueError(
            f"components must be >= 1 (Gaussians in the mixture over a slot's next "
            f"state), got {h.components}"
        )
    if h.stop_component and h.components < 2:
        raise ValueError(
            f"stop_component needs components >= 2 (one Gaussian for stopping, the "
            f"others for moving on), got components={h.components}"
        )
    if h.landing_component and h.components < 2 + h.stop_component:
        raise ValueError(
            f"landing_component needs components >= {2 + h.stop_component} (one "
            f"Gaussian for landing{', one for stopping' if h.stop_component else ''}"
            f", the others for moving on), got components={h.components}"
        )
    if not h.landing_change and not h.landing_component:
        raise ValueError(
            "landing_change: false needs landing_component: true (it is the "
            "landing Gaussian's learned change that it leaves out)"
        )
    if h.pivot_landing and not h.landing_component:
        raise ValueError(
            "pivot_landing needs landing_component: true (it says where the "
            "landing Gaussian lays an object), got landing_component=false"
        )
    if not 0 <= h.withhold <= 1 or h.withhold_frames < 1:
        raise ValueError(
            f"withhold must be in [0, 1] (a share of each clip's objects) and "
            f"withhold_frames >= 1, got {h.withhold}, {h.withhold_frames}"
        )
    if h.carry not in CARRIES:
        raise ValueError(
            f"carry must be one of {CARRIES} (what a carrier passes on to the "
            f"objects resting on it), got {h.carry!r}"
        )
    if h.falling_lands and not h.stop_component:
        raise ValueError(
            "falling_lands needs stop_component: true (it leaves the stopping "
            "Gaussian out for a falling object), got stop_component=false"
        )
    if not 0 <= h.fall_gain <= MAX_MOVE:
        raise ValueError(
            f"fall_gain must be in [0, {MAX_MOVE}] (m a frame by which a falling "
            f"object's downward move grows; 0.392 at 15 frames over 3 s), got "
            f"{h.fall_gain}"
        )
    if h.carry == "support" and not h.stop_component:
        raise ValueError(
            "carry: support needs stop_component: true (it moves the stopping "
            "Gaussian with what the object rests on), got stop_component=false"
        )
    optimization.check_schedule(h.lr_schedule)


class ObjectStateModel(SurpriseModel):
    """Slot dynamics over perfectly perceived object states, the package's positive control;
    its defaults are the published control (``configs/object_state.yaml``; how each part came
    to be: docs/study/archive/positive_control_rounds.md).

    Each mask id is a slot, created when the id is first seen. Per frame t, from the slots
    after frame t-1, the model predicts every known slot's state at t (a mixture of Gaussians,
    ``_mixture``: each mean the belief moved on by inertia, ``_inertia``, plus a learned
    change, never below the floor), its shape (a categorical) and whether it is seen (a
    Bernoulli on the sight lines to the boxes at the predicted states, ``_visibility_logit``);
    a context over the known slots predicts whether a new object appears. The most probable
    Gaussian is the predicted state, which a hidden slot's belief follows unless a prior holds
    it where it rests (``_holding``). Then the frame's observations update the beliefs and,
    through an interaction network over slot pairs, a GRU per slot. Training minimises the
    negative log-likelihood (NLL) of the training clips' frames, some seen objects withheld
    for a few frames so that tracking a hidden object learns from targets. Surprise at frame t
    is the rectified excess of each term's NLL over its entropy (``_per_frame``).

    Given, not learned (priors, each an argument here): the floor, the stopping, landing and
    pivoting geometry, support carrying, holding still, slowing, falling lands, the fall's
    gain and shared identity.

    Args:
        hidden_size: recurrent state per slot and width of the MLPs.
        message_size: size of the summed pair messages.
        use_camera: the core and visibility read the camera pose (else a fixed default pose).
        min_std: floor of the predicted standard deviations (a perfect perception's precision).
        components: Gaussians in the mixture over each slot's next state (1: one Gaussian).
        stop_component: the first Gaussian holds the object where it is (no inertia).
        landing_component: the last Gaussian lays the object down, size and colour kept.
        pivot_landing: it lays it down turned about its box's lowest corner onto a known
            object's top (``pivoted_down``), else flat on the floor (``lying_on_floor``).
        landing_change: the landing Gaussian takes the learned change too (false: inertia only).
        carry: ``"support"``: what rests on a known object moves with it, held there unseen
            (``resting_on``); ``"none"``: no carrying.
        hold_still: an unseen object last seen still on the floor stays where it is.
        slowing: what was slowing goes on slowing to a stop, never turning back (``slowed``).
        falling_lands: no stopping Gaussian for an object whose last move took it down.
        fall_gain: a falling object's downward move grows by this much a frame (m; g·Δt² =
            0.392 at the generator's 15 frames over 3 s; 0: off).
        shared_identity: every Gaussian predicts the size and colour last believed, with one
            learned spread.
        withhold: share of each training clip's objects withheld for a span of frames
            (``withheld_spans``; 0: never).
        withhold_frames: the longest withheld span, in frames.
        hard_assignment: training scores a seen state by its best-explaining Gaussian alone
            (surprise and validation use the whole mixture).
        learning_rate: Adam's (peak) learning rate.
        lr_schedule: ``"constant"`` or ``"cosine"`` (decays to 0 at ``trainer.max_steps``).
        training_frames: frames per training clip, recorded from the training batches.
    """

    ARCHITECTURE = ARCHITECTURE
    TRAINING_ONLY = (
        "learning_rate",
        "lr_schedule",
        "withhold",
        "withhold_frames",
        "hard_assignment",
    )
    SURPRISE = (
        "the rectified excess surprisal of the seen object states (each term's negative "
        "log-likelihood less its entropy, where positive: the visibility, state and shape "
        "of every known object, and any newcomer's appearance)"
    )

    def __init__(
        self,
        hidden_size: int = 128,
        message_size: int = 64,
        use_camera: bool = True,
        min_std: float = 0.01,
        components: int = 4,
        stop_component: bool = True,
        landing_component: bool = True,
        pivot_landing: bool = True,
        landing_change: bool = True,
        carry: str = "support",
        hold_still: bool = True,
        slowing: bool = True,
        falling_lands: bool = True,
        fall_gain: float = 0.392,
        shared_identity: bool = True,
        withhold: float = 0.5,
        withhold_frames: int = 8,
        hard_assignment: bool = True,
        learning_rate: float = 1e-3,
        lr_schedule: str = "cosine",
        training_frames: int | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        _check_arguments(self.hparams)
        hidden, message = hidden_size, message_size
        self.message = PairNetwork(hidden, hidden, hidden, message)
        self.update = nn.GRUCell(FEATURES + message + CAMERA_FEATURES, hidden)
        floor = FLOOR_FEATURES if landing_component else 0
        self.dynamics = mlp(
            [
                hidden + message + CAMERA_FEATURES + floor,
                hidden,
                hidden,
                self._dynamics_outputs(components),
            ]
        )
        self.occlusion = PairNetwork(hidden, 0, hidden, message)
        self.visibility = mlp([hidden + message + VIEW + 3 + CAMERA_FEATURES, hidden, 1])
        #: How much the visibility logit starts from geometry (``seen_by_geometry``); learned.
        self.geometry_weight = nn.Parameter(torch.ones(()))
        self.appearance = mlp([hidden + CAMERA_FEATURES, hidden, 1 + 2 * STATE_SIZE + SHAPES])
        self.log_min_std = math.log(min_std)
        #: Per component, how much of the inertia its mean takes (``stop_component``: none for
        #: the first).
        keeps = torch.ones(components, 1)
        if stop_component:
            keeps[0] = 0.0
        self.register_buffer("inertia_kept", keeps, persistent=False)

    @staticmethod
    def _dynamics_outputs(components: int) -> int:
        """Per slot: each component's change and log-std, the components' logits (none for
        one component) and the shape's logits."""
        return components * 2 * STATE_SIZE + (components if components > 1 else 0) + SHAPES

    # ----------------------------------------------------------------------------- inputs
    def _inputs(
        self, frames: torch.Tensor, objects: TensorDictBase | None, camera: torch.Tensor | None
    ) -> Observations:
        if objects is None:
            raise ValueError(
                "the object-state model (the positive control) reads each video's object "
                f"states (batch key 'objects', specs.objects_spec), but a batch of "
                f"{tuple(frames.shape[:2])} videos came without them; use the package's "
                "generated records (GENERATOR_VERSION 3 or later)"
            )
        steps = frames.shape[1]
        if camera is None or not self.hparams.use_camera:
            camera = torch.tensor([0.0, 0.0, 0.4, 4.0, 90.0, -20.0], device=self.device)
            camera = camera.expand(frames.shape[0], steps, 6)
        return observe(objects.to(self.device), camera.to(self.device))

    # ----------------------------------------------------------------------------- core
    @staticmethod
    def _pairs(state: torch.Tensor, shape: torch.Tensor, seen_as: torch.Tensor) -> torch.Tensor:
        """Pair features [B, S_i, S_j, PAIR_FEATURES] of slot j seen from slot i (``seen_as``:
        each slot's ``view``)."""
        slots = state.shape[1]

        def other_minus_self(values):
            return values[:, None, :] - values[:, :, None]

        def other(values):
            return values[:, None].expand(-1, slots, -1, -1)

        def own(values):
            return values[:, :, None].expand(-1, -1, slots, -1)

        centre, half = seen_as[..., BOX_CENTRE], seen_as[..., BOX_HALF]
        # the share of i's image box along right and up that j's spans
        overlap = (
            (other(half) + own(half) - other_minus_self(centre).abs())
            / (2 * own(half)).clamp(min=1e-3)
        ).clamp(0, 1)
        return torch.cat(
            [
                other_minus_self(state[..., POSITION]),
                other_minus_self(seen_as[..., CAMERA_XYZ]),
                other_minus_self(centre),
                other(state[..., SIZE]),
                own(state[..., SIZE]),
                other(half),
                own(half),
                overlap,
                overlap.prod(-1, keepdim=True),
                other(state[..., ORIENTATION]),
                other(shape),
            ],
            dim=-1,
        )

    @staticmethod
    def _pair_weight(known: torch.Tensor) -> torch.Tensor:
        """1 for pairs (i, j) of known slots with j != i [B, S, S, 1]."""
        weight = known[:, None, :] & known[:, :, None]
        eye = torch.eye(known.shape[1], dtype=torch.bool, device=known.device)
        return (weight & ~eye).float()[..., None]

    def _messages(
        self,
        network: PairNetwork,
        own: torch.Tensor,
        other: torch.Tensor | None,
        pairs: torch.Tensor,
        known: torch.Tensor,
    ) -> torch.Tensor:
        """Sum over the other known slots j of network(own_i, other_j, pair_ij) [B, S, M]."""
        return (network(own, other, pairs) * self._pair_weight(known)).sum(2)

    def rollout(
        self, observations: Observations, withheld: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """Run the slots through a batch's frames. Returns, per frame and slot [B, T, S], the
        negative log-likelihood of the visibility, state and shape seen (0 where they do not
        apply) and the entropy of each prediction (``<term>_entropy``), ``appear`` and
        ``appear_entropy`` [B, T] (the appearance term), the beliefs after each frame and the
        states predicted for it (frame 0: none) [B, T, S, 13], the predicted visibility
        probability [B, T, S], ``known`` [B, T, S] (seen at some frame <= t) and the slots'
        recurrent states [B, T, S, H].

        ``withheld`` (bool [B, T, S], training only): frames at which a known slot's
        observation is kept from the model, which rolls it forward as if it were hidden, while
        what it shows is still scored: a hidden object's rollout learns from targets
        (``withheld_spans``)."""
        obs = observations
        batch, steps, slots = obs.visible.shape
        hidden = obs.state.new_zeros(batch, slots, self.hparams.hidden_size)
        belief = obs.state.new_zeros(batch, slots, STATE_SIZE)
        shape = obs.state.new_zeros(batch, slots, SHAPES)
        velocity = obs.state.new_zeros(batch, slots, 3)
        acceleration = velocity  # the change of the last move
        known = torch.zeros(batch, slots, dtype=torch.bool, device=obs.state.device)
        given_before = known  # what reached the model at the frame before (none before 0)
        holding = None  # which slots stay where they rest (``Holding``); none before frame 1
        still = torch.ones_like(known)  # not seen moving across the floor when last seen twice
        terms = {key: [] for name in SLOT_TERMS + ("appear",) for key in (name, f"{name}_entropy")}
        beliefs, predictions, probability, knowns, states = [], [], [], [], []
        for t in range(steps):
            pose = obs.camera[:, t]
            pose_features = camera_features(pose)[:, None].expand(-1, slots, -1)
            visible = obs.visible[:, t]
            new = visible & ~known
            # what reaches the model: the seen slots, less a known one's withheld observation
            given = visible & ~(withheld[:, t] & known) if withheld is not None else visible
            if t == 0:
                predicted = belief
                for key in terms:
                    terms[key].append(
                        obs.state.new_zeros(batch, *(() if key.startswith("appear") else (slots,)))
                    )
                probability.append(obs.state.new_zeros(batch, slots))
            else:
                slots_before = Slots(hidden, belief, shape, velocity, acceleration, known, still)
                predicted, step_terms, seen_probability, holding = self._predict(
                    slots_before, known & ~given_before, pose, pose_features, obs, t
                )
                for key, value in step_terms.items():
                    terms[key].append(value)
                probability.append(seen_probability)
            predictions.append(predicted)
            # observe frame t: seen slots take what is seen, hidden ones their prediction or,
            # held, where they rest, moved on by what their support was seen to do beyond its
            # own prediction
            if holding is not None:
                hidden_now = (~given)[..., None]
                correction = (
                    (obs.state[:, t, :, POSITION] - predicted[..., POSITION]) * given[..., None]
                ).detach()
                carried = torch.einsum("bij,bjk->bik", holding.rests, correction) * hidden_now
                predicted = torch.where(
                    holding.holds[..., None] & hidden_now, holding.state, predicted
                ) + F.pad(carried, (0, STATE_SIZE - 3))
            previous = belief
            belief = torch.where(given[..., None], obs.state[:, t], predicted)
            # the last move: seen in both frames, what was seen; else what was predicted (a
            # reappearing object's jump from its predicted place is a correction, not a move)
            steady = (given & given_before)[..., None]
            move = torch.where(steady, belief, predicted)[..., POSITION] - previous[..., POSITION]
            moving = move * (known & ~new)[..., None].float()  # known before t
            acceleration, velocity = moving - velocity, moving
            still = torch.where(steady[..., 0], velocity[..., :2].norm(dim=-1) < MOVING, still)
            shape = torch.where(given[..., None], obs.shape[:, t], shape)
            known = known | visible
            given_before = given
            seen_as = view(belief, pose)
            features = torch.cat(
                [
                    belief,
                    shape,
                    (obs.fraction[:, t] * given)[..., None],
                    seen_as,
                    velocity,
                    given[..., None].float(),
                ],
                dim=-1,
            )
            pairs = self._pairs(belief, shape, seen_as)
            message = self._messages(self.message, hidden, hidden, pairs, known)
            step_input = torch.cat([features, message, pose_features], dim=-1)
            hidden = self.update(step_input.flatten(0, 1), hidden.flatten(0, 1)).view_as(hidden)
            hidden = hidden * known[..., None]
            belief = belief * known[..., None]
            beliefs.append(belief)
            knowns.append(known)
            states.append(hidden)
        return {
            **{key: torch.stack(values, dim=1) for key, values in terms.items()},
            "belief": torch.stack(beliefs, dim=1),
            "predicted": torch.stack(predictions, dim=1),
            "visible_probability": torch.stack(probability, dim=1),
            "known": torch.stack(knowns, dim=1),
            "hidden": torch.stack(states, dim=1),
        }

    def _predict(
        self,
        slots: Slots,
        unseen: torch.Tensor,
        pose: torch.Tensor,
        pose_features: torch.Tensor,
        obs: Observations,
        t: int,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor, Holding | None]:
        """Frame t's predictions from the slots after frame t-1: the predicted states [B, S, 13]
        (the most probable Gaussian's mean, or where ``_holding`` holds a slot not given at t-1,
        ``unseen`` [B, S]), the terms of what frame t shows (``rollout``), p(visible) [B, S] and
        the ``Holding`` of every known slot (None without ``carry: support`` or ``hold_still``)."""
        pairs = self._pairs(slots.belief, slots.shape, view(slots.belief, pose))
        message = self._messages(self.message, slots.hidden, slots.hidden, pairs, slots.known)
        falling = slots.velocity[..., 2] < -MOVING  # [B, S]: its last move took it down
        inertia = self._inertia(slots, falling)
        mixture, shape_logits = self._mixture(slots, message, pose_features, inertia, falling)
        predicted, mixture, holding = self._holding(slots, mixture, unseen)
        logit = self._visibility_logit(slots, predicted, pose, pose_features)
        visible = obs.visible[:, t]
        seen, keep = visible.float(), slots.known.float()
        hard = self.training and self.hparams.hard_assignment
        terms = {}
        for name, (nll, entropy), weight in (
            ("visibility", bernoulli_nll(logit, seen), keep),
            (
                "state",
                mixture_nll(
                    obs.state[:, t], mixture.means, mixture.log_std, mixture.logits, hard=hard
                ),
                seen * keep,
            ),
            ("shape", categorical_nll(shape_logits, obs.shape[:, t]), seen * keep),
        ):
            terms[name], terms[f"{name}_entropy"] = nll * weight, entropy * weight
        terms.update(
            self._appearance(
                slots.hidden,
                slots.known,
                pose,
                visible & ~slots.known,
                obs.state[:, t],
                obs.shape[:, t],
            )
        )
        return predicted, terms, torch.sigmoid(logit) * keep, holding

    def _inertia(self, slots: Slots, falling: torch.Tensor) -> torch.Tensor:
        """Where its last move takes each slot [B, S, 13] (positions only): that move, slowed as
        it was slowing (``slowing``) and, falling, grown by ``fall_gain``; bounded by
        ``MAX_MOVE``, so a hidden object's rollout cannot feed on itself and diverge."""
        move = slots.velocity
        if self.hparams.slowing:
            move = slowed(slots.velocity, slots.acceleration)
        if self.hparams.fall_gain:  # what falls, falls faster
            move = move - F.pad(falling[..., None] * self.hparams.fall_gain, (2, 0))
        return F.pad(move.clamp(-MAX_MOVE, MAX_MOVE), (0, STATE_SIZE - 3))

    def _mixture(
        self,
        slots: Slots,
        message: torch.Tensor,
        pose_features: torch.Tensor,
        inertia: torch.Tensor,
        falling: torch.Tensor,
    ) -> tuple[Mixture, torch.Tensor]:
        """The mixture over each slot's next state and its shape's logits [B, S, 7]: each mean
        the belief moved on by inertia (none for the stopping Gaussian) plus a learned change,
        never below the floor; the last one laid down (``_landing``); the stopping Gaussian
        left out for what falls (``falling_lands``)."""
        belief, components = slots.belief, self.hparams.components
        inputs = [slots.hidden, message, pose_features]
        if self.hparams.landing_component:  # how high the box's lowest point is, now and next
            inputs.append(torch.stack([lowest_point(belief), lowest_point(belief + inertia)], -1))
        change, log_std, logits, shape_logits = self.dynamics(torch.cat(inputs, dim=-1)).split(
            [
                components * STATE_SIZE,
                components * STATE_SIZE,
                components if components > 1 else 0,
                SHAPES,
            ],
            -1,
        )
        change = change.unflatten(-1, (components, STATE_SIZE))  # [B, S, K, 13]
        log_std = log_std.unflatten(-1, (components, STATE_SIZE))
        if not self.hparams.landing_change:  # the landing Gaussian: where inertia takes it
            landing_identity = F.pad(change[:, :, -1:, IDENTITY], (IDENTITY.start, 0))
            change = torch.cat([change[:, :, :-1], landing_identity], dim=2)
        if self.hparams.shared_identity:  # size and colour kept, under one spread for all
            change = torch.cat([change[..., POSE], torch.zeros_like(change[..., IDENTITY])], -1)
            shared = log_std[..., :1, IDENTITY].expand(*log_std.shape[:-1], -1)
            log_std = torch.cat([log_std[..., POSE], shared], -1)
        moved = (
            belief[:, :, None] + self.inertia_kept * inertia[:, :, None]
        ) + MAX_MOVE * torch.tanh(change / MAX_MOVE)
        means = on_or_above_floor(moved)
        if self.hparams.landing_component:
            landing = self._landing(moved[:, :, -1], slots)[:, :, None]
            means = torch.cat([means[:, :, :-1], landing], dim=2)
        log_std = self.log_min_std + F.softplus(log_std - self.log_min_std)
        logits = logits if components > 1 else None
        if self.hparams.falling_lands:  # nothing stops in mid-air: it lands or falls on
            stopping = torch.arange(components, device=falling.device) == 0
            logits = logits.masked_fill(falling[..., None] & stopping, LEFT_OUT)
        return Mixture(means, log_std, logits), shape_logits

    def _landing(self, moved: torch.Tensor, slots: Slots) -> torch.Tensor:
        """The landing Gaussian's mean [B, S, 13]: the object where its pose ``moved`` to, as
        the object it is (size and colour kept), turned down about its lowest corner onto a
        known object's top or the floor (``pivot_landing``), else laid flat on the floor."""
        landing = torch.cat([moved[..., POSE], slots.belief[..., IDENTITY]], dim=-1)
        if self.hparams.pivot_landing:
            return pivoted_down(on_or_above_floor(landing), slots.belief, slots.shape, slots.known)
        return lying_on_floor(landing)

    def _holding(
        self, slots: Slots, mixture: Mixture, unseen: torch.Tensor
    ) -> tuple[torch.Tensor, Mixture, Holding | None]:
        """The predicted states [B, S, 13], the mixture with its stopping Gaussian carried by
        what each slot rests on (``carry: support``), and the ``Holding``: an unseen slot
        resting on a known one, or last seen still on the floor (``hold_still``), is held
        there. Without either prior: the most probable means, the mixture, None."""
        predicted = mixture.most_probable()
        if not (self.hparams.carry == "support" or self.hparams.hold_still):
            return predicted, mixture, None
        belief, known = slots.belief, slots.known
        rests = belief.new_zeros(*known.shape, known.shape[1])
        carried = torch.zeros_like(belief)
        if self.hparams.carry == "support":  # what rests on a known object moves with it
            rests = resting_on(belief.detach(), slots.shape, known)
            moves = ((predicted - belief)[..., POSITION] * known[..., None]).detach()
            carried = F.pad(torch.einsum("bij,bjk->bik", rests, moves), (0, STATE_SIZE - 3))
            stopping = on_or_above_floor(mixture.means[:, :, 0] + carried)[:, :, None]
            mixture = replace(mixture, means=torch.cat([stopping, mixture.means[:, :, 1:]], 2))
            predicted = mixture.most_probable()
        holds = rests.sum(-1) > 0
        if self.hparams.hold_still:  # what was still when seen and lies on the floor
            holds = holds | (slots.still & (lowest_point(belief) <= REST_TOLERANCE))
        holding = Holding(rests, holds, belief + carried)
        predicted = torch.where((unseen & holds)[..., None], holding.state, predicted)
        return predicted, mixture, holding

    def _visibility_logit(
        self, slots: Slots, predicted: torch.Tensor, pose: torch.Tensor, pose_features: torch.Tensor
    ) -> torch.Tensor:
        """The logit [B, S] that each slot is seen at t: sight lines to every known box at its
        predicted state (``seen_by_geometry``) times a learned weight, plus a learned term from
        its view against the others'. No gradient reaches the states from it: a hidden object's
        place is what the dynamics learned from seen motion predicts, not one bent to explain
        why it is not seen (with it, a cube behind a container drifted in, where walls hide it)."""
        placed = predicted.detach()
        seen_as = view(placed, pose)
        pairs = self._pairs(placed, slots.shape, seen_as)
        occluders = self._messages(self.occlusion, slots.hidden, None, pairs, slots.known)
        geometry = seen_by_geometry(placed, slots.shape, slots.known, pose).clamp(0.02, 0.98)
        learned = self.visibility(
            torch.cat([slots.hidden, occluders, seen_as, placed[..., SIZE], pose_features], dim=-1)
        )
        return learned.squeeze(-1) + self.geometry_weight * torch.logit(geometry)

    def _appearance(
        self,
        hidden: torch.Tensor,
        known: torch.Tensor,
        pose: torch.Tensor,
        new: torch.Tensor,
        state: torch.Tensor,
        shape: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """The appearance terms of frame t and their entropies: ``appear`` [B], a Bernoulli of
        whether any new object appears, given the mean state of the known slots and the pose;
        ``newcomer_state`` and ``newcomer_shape`` [B, S], each newcomer's state (Gaussian) and
        shape (categorical)."""
        weight = known.float()[..., None]
        context = (hidden * weight).sum(1) / weight.sum(1).clamp(min=1)
        out = self.appearance(torch.cat([context, camera_features(pose)], dim=-1))
        logit, mean, log_std, shape_logits = out.split([1, STATE_SIZE, STATE_SIZE, SHAPES], -1)
        log_std = self.log_min_std + F.softplus(log_std - self.log_min_std)
        newcomers = new.float()
        terms = {}
        for name, (nll, entropy), weight in (
            ("appear", bernoulli_nll(logit.squeeze(-1), new.any(-1).float()), 1.0),
            ("newcomer_state", gaussian_nll(state, mean[:, None], log_std[:, None]), newcomers),
            ("newcomer_shape", categorical_nll(shape_logits[:, None], shape), newcomers),
        ):
            terms[name], terms[f"{name}_entropy"] = nll * weight, entropy * weight
        return terms

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
        frames = self._frames_of(batch)
        inputs = video_inputs(batch)
        observations = self._inputs(frames, inputs.get("objects"), inputs.get("camera"))
        withheld = withheld_spans(
            observations.visible.shape,
            self.hparams.withhold,
            self.hparams.withhold_frames,
            observations.visible.device,
        )
        out = self.rollout(observations, withheld)
        clips = frames.shape[0]
        terms = {
            name: out[name].sum() / clips  # the negative log-likelihood of the clips
            for name in SLOT_TERMS + ("appear",)
        }
        terms["loss"] = sum(terms.values())
        self._check_finite(terms)
        self.log("train/loss", terms["loss"], prog_bar=True, batch_size=clips)
        for name, value in terms.items():
            if name != "loss":
                self.log(f"train/{name}", value, batch_size=clips)
        return terms["loss"]

    def configure_optimizers(self) -> dict:
        return optimization.adam(
            self.parameters(),
            self.hparams.learning_rate,
            self.hparams.lr_schedule,
            getattr(self._trainer, "max_steps", None),
        )

    # ----------------------------------------------------------------------------- protocol
    @torch.no_grad()
    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """Per-frame surprise [B, T] (float32): the NLL of what is seen (class docstring)."""
        out = self.rollout(self._inputs(frames, objects, camera))
        return self._per_frame(out).float()

    @torch.no_grad()
    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """What the model expected [B, T, 3, H, W]: each known slot's expected state drawn as an
        ellipse of its colour where and as large as its box is seen, as opaque as the predicted
        probability that it is seen (frame 0: what is seen), nearer objects over farther."""
        observations = self._inputs(frames, objects, camera)
        out = self.rollout(observations)
        belief = torch.cat([out["belief"][:, :1], out["predicted"][:, 1:]], dim=1)
        opacity = torch.cat(
            [observations.visible[:, :1].float(), out["visible_probability"][:, 1:]], dim=1
        )
        return draw_ellipses(belief, opacity, observations.camera, frames.shape[2:4])

    @torch.no_grad()
    def trajectories(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> dict[str, torch.Tensor]:
        """``slots`` [B, T, H]: the mean recurrent state of the known slots at each frame."""
        out = self.rollout(self._inputs(frames, objects, camera))
        weight = out["known"].float()[..., None]
        return {"slots": (out["hidden"] * weight).sum(2) / weight.sum(2).clamp(min=1)}


def slowed(move: torch.Tensor, change: torch.Tensor) -> torch.Tensor:
    """The next move [..., 3] of an object that goes on slowing as its last ``move`` was slowed
    by its ``change`` (both [..., 3]): the move along the floor (x, y) less the part of the change
    that opposed it, never past standstill (it stops, it does not turn back); the vertical move,
    and a change that speeds the object up or turns it, are left as they were."""
    along_floor = move[..., :2]
    speed = along_floor.square().sum(-1, keepdim=True).add(1e-12).sqrt()
    braking = (-(change[..., :2] * along_floor).sum(-1, keepdim=True) / speed).clamp(min=0)
    kept = (1 - braking / speed).clamp(0, 1)
    return torch.cat([along_floor * kept, move[..., 2:]], dim=-1)


def withheld_spans(
    shape: torch.Size, share: float, longest: int, device: torch.device
) -> torch.Tensor | None:
    """Training's withheld observations, bool [B, T, S]: each (clip, slot) with probability
    ``share`` gets one span of 1 to ``longest`` frames, starting at a frame from 1 on, during
    which the model is not told what it sees. An object truly hidden in a clip has no target
    until it reappears, so without these spans a hidden object's rollout learns only from that
    frame, and drifts (a cube at rest behind a container: 0.2 m over nine frames). None if
    there is nothing to withhold."""
    if share <= 0:
        return None
    batch, steps, slots = shape
    chosen = torch.rand(batch, 1, slots, device=device) < share
    start = torch.randint(1, max(steps, 2), (batch, 1, slots), device=device)
    length = torch.randint(1, longest + 1, (batch, 1, slots), device=device)
    time = torch.arange(steps, device=device)[None, :, None]
    return chosen & (time >= start) & (time < start + length)


class PairNetwork(nn.Module):
    """An MLP over [own_i, other_j, pair_ij] for every slot pair, with its first layer split
    by input: the slots' parts are computed once per slot, not once per pair (S times less)."""

    def __init__(self, own_size: int, other_size: int, hidden_size: int, output_size: int):
        super().__init__()
        self.own = nn.Linear(own_size, hidden_size)
        self.other = nn.Linear(other_size, hidden_size, bias=False) if other_size else None
        self.pair = nn.Linear(PAIR_FEATURES, hidden_size, bias=False)
        self.out = nn.Linear(hidden_size, output_size)

    def forward(
        self, own: torch.Tensor, other: torch.Tensor | None, pairs: torch.Tensor
    ) -> torch.Tensor:
        """own [B, S, O], other [B, S, P] (or None), pairs [B, S, S, F] -> [B, S, S, out]."""
        first = self.own(own)[:, :, None] + self.pair(pairs)
        if self.other is not None:
            first = first + self.other(other)[:, None]
        return self.out(torch.relu(first))

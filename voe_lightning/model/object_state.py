"""The positive control: an object-state learner with perfect perception. It reads what a
perfect 3D perception system would hand to physics (per frame, the states of the objects visible
at that frame, ``specs.objects_spec``, hidden ones masked out, and the camera pose), learns their
dynamics from the training clips, tracks hidden objects forward, and is surprised by the negative
log-likelihood of what is then seen. If it cannot show VOE on a concept, the stimuli are wrong."""

from __future__ import annotations

import math
from dataclasses import dataclass

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
from voe_lightning.model.object_geometry import (
    REST_TOLERANCE,
    VIEW,
    draw_ellipses,
    lowest_point,
    lying_on_floor,
    on_or_above_floor,
    on_what_is_below,
    pivoted_down,
    resting_on,
    seen_by_geometry,
    view,
    world_half_extents,
)

#: The continuous state of an object that the model predicts: position (3), orientation (4),
#: size (3), colour (3). A sphere's orientation cannot be seen, so it reads as the identity.
STATE_SIZE = 13
SHAPES = len(specs.OBJECT_SHAPES)
SPHERE = specs.OBJECT_SHAPES.index("sphere")
#: Per-slot features the recurrent core reads: the state, its shape (one-hot), its visible share,
#: its view, its velocity and whether it is seen.
FEATURES = STATE_SIZE + SHAPES + 1 + VIEW + 3 + 1
#: Pair features: the other object's position, camera coordinates and image-box centre relative
#: to this one's, both sizes, both image-box half-extents, how much of this one's image box the
#: other's covers (along right, up, and both), (with ``world_boxes``, WORLD_BOX_FEATURES,) the
#: other's orientation and shape.
PAIR_FEATURES = 3 + 3 + 2 + 3 + 3 + 2 + 2 + 3 + 4 + SHAPES
#: How much of this one's world box the other's spans (along x, y, z) and how far this one's
#: bottom is above the other's top: what it could rest on, sit in, or be carried by.
WORLD_BOX_FEATURES = 3 + 1
#: The largest move of a state in one frame interval, in each of the inertia and the learned
#: change (metres for positions; our fastest object, a falling block, moves 0.6 m a frame).
MAX_MOVE = 1.5
#: A seen object starts to move at frame t when it moved less than RESTING metres into frame t-1
#: and more than MOVING into frame t (``motion_onsets``).
RESTING, MOVING = 0.005, 0.02
#: The logit that takes a Gaussian out of the mixture (``falling_lands``): finite, so that its
#: share of the entropy is 0 * finite, not 0 * inf.
LEFT_OUT = -1.0e4
#: The per-slot terms of a frame's negative log-likelihood; ``appear`` is per frame.
SLOT_TERMS = ("visibility", "state", "shape", "newcomer_state", "newcomer_shape")

#: Constructor arguments that shape the parameters, or the priors they were trained with: a
#: checkpoint must agree on all of them.
ARCHITECTURE = ("hidden_size", "message_size", "use_camera", "components", "stop_component",
                "landing_component", "land_on_objects", "pivot_landing", "landing_change",
                "carry", "hold_still",
                "slowing", "falling_lands", "fall_gain", "shared_identity", "world_boxes")
#: Per-slot inputs of the dynamics with ``landing_component``: how high the lowest point of the
#: object's box is above the floor at its belief and where its inertia would take it.
FLOOR_FEATURES = 2
#: The carry logit's start (own move: 0): objects start out moving mostly on their own.
CARRY_START = -2.0
#: What a carrier passes on (``carry``): nothing, its last move (the mover's own taken off),
#: or the change of its last move, by learned shares; or, to what rests on it, its whole move.
CARRIES = ("none", "velocity", "acceleration", "support")


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
    picked = {name: value.gather(2, ids[:, None].expand(-1, steps, -1).reshape(
                  *ids.shape[:1], steps, slots, *([1] * (value.dim() - 3))
              ).expand(-1, -1, -1, *value.shape[3:]))
              for name, value in objects.items()}  # [B, T, S, ...]
    visible = picked["visible_fraction"] > 0
    label = picked["shape_label"].long()
    orientation = picked["orientation"].float()
    orientation = orientation * torch.where(orientation[..., :1] < 0, -1.0, 1.0)  # w >= 0
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], device=orientation.device)
    orientation = torch.where((label == SPHERE)[..., None], identity, orientation)
    state = torch.cat([picked["position"].float(), orientation, picked["size"].float(),
                       picked["color"].float()], dim=-1)
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


class ObjectStateModel(SurpriseModel):
    """Slot dynamics over perfectly perceived object states, the package's positive control.

    Each mask id is a slot, created when the id is first seen (nothing earlier depends on it).
    Per step t, from the slots' recurrent states after frame t-1 and their beliefs (the last
    state seen, or, while hidden, the state predicted for them, so a hidden object is tracked
    forward), the model predicts for every known slot its state at t (a mixture of
    ``components`` Gaussians: each mean = belief, moved on by inertia (the last frame's move;
    with ``carry``, plus a share of a carrier's), plus a learned change, and never below the
    floor; learned standard deviations and weights; its shape as a categorical). A mixture,
    because at five frames a second a contact is an either-or: a falling plank has landed flat
    by the next frame or is still in the air or propped up, and one Gaussian's mean sits
    between them, where neither happens. The most probable component is the slot's predicted
    state (what a hidden slot's belief follows, unless a prior holds it where it rests:
    ``carry: support``, ``hold_still``) and its visibility at t (a
    Bernoulli whose logit is that of ``seen_by_geometry``, what sight lines to the objects'
    boxes at the predicted states would show, times a learned weight, plus a learned term from
    its view against every other slot's). A context over the known slots predicts whether a
    new object appears at t and, if so, its state. Then the frame's observations update the
    beliefs and, through an interaction network over slot pairs, a GRU per slot.

    What frame t shows has a negative log-likelihood (NLL): for each known slot the visibility
    term, plus where visible the state and shape terms; plus the appearance terms (whether some
    new object appears, and each newcomer's state and shape). Training minimises it summed over
    the training clips' frames, with some seen objects' observations withheld for a few frames
    (``withhold``), so that rolling a hidden object forward is learned against what it then
    showed (and, with ``withhold_onsets``, every object that another sets moving, from that
    frame). Surprise at frame t (frame 0: 0) is its rectified excess: each
    term's NLL less its expectation under the prediction (the entropy), where positive
    (``_per_frame`` says why).

    Args:
        hidden_size: recurrent state per slot and width of the MLPs.
        message_size: size of the summed pair messages.
        use_camera: the core and visibility read the camera pose; without it, camera
            coordinates are taken from a fixed default pose.
        min_std: floor of the predicted standard deviations (metres for positions): the
            precision of a perfect perception system.
        components: Gaussians in the mixture over each slot's next state (1: one Gaussian).
        stop_component: the first Gaussian starts from the belief without the inertia: the
            hypothesis that the object stops where it is (a plank landing on what is under
            it, a ball meeting a wall), so that whether it stops or moves on can be the
            mixture's choice rather than a regression of the change. Alone, it held a hidden
            ball behind its pillar (docs/study/archive/positive_control_rounds.md, round seven).
        landing_component: the last Gaussian lays the object, moved on by inertia and its
            learned change, flat on the floor (``lying_on_floor``), its size and colour kept
            (with hard assignment a learned change there drifted, so it never won, and never
            learned): the hypothesis that it lands, which a steeply falling plank does within
            one frame interval; and the dynamics read how high each box's lowest point is now
            and would be by inertia (``FLOOR_FEATURES``), so the mixture can tell when. Without
            it, a plank still predicted tilted was held at its half-height by the floor (round
            eight).
        land_on_objects: the landing Gaussian lays the object on the highest known object
            below it, where there is one, instead of the floor (``on_what_is_below``): a
            plank falling onto a hidden object lands on it if the object is still believed to
            be there. On the floor alone, planks were predicted flat where they were propped
            (round nine).
        pivot_landing: the landing Gaussian turns the object about the lowest corner of its
            box until its underside meets the top of a known object, else flat on the floor
            (``pivoted_down``), instead of laying it flat in place: a plank whose front edge
            has landed falls back onto the object believed under it. Laid flat first and then
            raised (``land_on_objects``), the object that propped a plank was not counted as
            under it, since the plank's lowest point was already below its top (round ten).
        landing_change: the landing Gaussian's mean starts, like the others', from the belief
            moved by inertia and a learned change of position and orientation; without it
            (false), from the belief moved by inertia alone, so where it lays the object is the
            geometry's. A learned change there let some seeds' landing Gaussian miss a plank
            already propped on the object by hundreds of nats of position while holding most of
            the weight (docs/study/archive/positive_control_rounds.md, round eighteen).
        carry: what each slot's inertia takes from a carrier (``CARRIES``), by learned
            shares over itself and the other known slots that sum to 1 (a ``PairNetwork``
            over each pair), so that a cube hidden in a container can move with it when it
            starts to slide, and a container and the rod pushing it do not carry it twice.
            ``"velocity"``: the carrier's last move less the slot's own; learned, it also held
            a block falling into a container at rest
            (docs/study/archive/positive_control_rounds.md, round five). ``"acceleration"``:
            the change of the carrier's last move, which a carrier at rest never has; trained
            only where a carrier starts or stops, in 3,000 steps its shares stayed shut
            (round six). ``"support"``: no shares; what an object rests on
            (``resting_on``: an open container's bottom, a box's top) carries it whole: the
            stopping Gaussian moves it by the support's predicted move, and while it is hidden
            its belief also takes what the support was seen to do beyond that prediction, so a
            cube hidden in a sliding container keeps its place in it (round twelve). A prior,
            like the floor's: not learned. ``"none"``: the move must be decoded from the
            other slot's recurrent state, and a hidden carried cube was left where it was seen
            (0.8 m off).
        hold_still: a known object not seen at the last frame that lies on the floor (its
            box's lowest point within ``REST_TOLERANCE``) and was still, not moving across the
            floor, the last time it was seen in two frames running, is held where it is: what
            lies still stays still unseen. Without it, a cube fallen behind a container drifted
            into it as the learned change fed on itself, and was then carried away with it
            (round twelve).
        slowing: an object's inertia goes on slowing it as its last move was slowed (the part of
            its last change of move that opposed its move along the floor), until it stops: it
            never turns back (``slowed``). A ball that rolls slowing to a stop behind a pillar
            stops there unseen; without it, the hidden rollout carried the last move on, and a
            seed that had not learned the slowing believed the ball rolled on 0.95 m (round
            thirteen). A prior, like the floor's: not learned.
        falling_lands: nothing stops in mid-air: the stopping Gaussian is left out for an
            object whose last move took it down by more than ``MOVING``, so it lands (the
            landing Gaussian) or falls on. A seed that held a block where it was one frame
            after it was let go expected it to stay in view, and read the block that sank out
            of sight as the violation (round fifteen). A prior: not learned.
        fall_gain: what falls, falls faster: an object whose last move took it down by more
            than ``MOVING`` has its inertia's downward move grown by this much a frame (m;
            gravity's g·Δt², 9.81 × 0.2² = 0.392 at the generator's 15 frames over 3 s; 0: off).
            Free fall is then inertia, the same for every object and frame. Without it, seeds
            whose mixture gave free fall to a moving Gaussian carried a released block on at its
            first frame's speed, 0.27 m a frame where it falls 0.60; learned from 0 instead, the
            gain stayed under 0.01 (round sixteen). A prior, like the floor's: not learned.
        shared_identity: the Gaussians differ only in where the object is and how it is turned:
            each predicts the size and colour it was last believed to have, with one learned
            spread shared by all (the first Gaussian's). Without it the landing Gaussian, which
            kept size and colour exactly, won a propped plank's resting frames by some 11 nats
            of size and colour under hard assignment, and its tight orientation then charged
            every frame of the plank's rocking (round seventeen).
        world_boxes: the pair features add how the two objects' world boxes overlap
            (``WORLD_BOX_FEATURES``).
        withhold: share of each training clip's objects whose observations are withheld for a
            span of frames (``withheld_spans``): the model rolls them forward as if hidden
            and is scored on what they show, so tracking a hidden object is learned from
            targets, not only where it reappears (0: never).
        withhold_frames: the longest withheld span, in frames.
        withhold_onsets: every object that another sets moving in a training clip
            (``motion_onsets``) is withheld from that frame for 2 to ``withhold_frames`` frames:
            what moves it (the container it sits in, the block that pushes it) must be read
            from the others, because its own last move says nothing. Without it, a seen cube
            carried by a container moves by inertia from the slide's second frame, so only a
            slide's first frame teaches carrying.
        hard_assignment: training scores a seen state by the mixture's best-explaining
            Gaussian alone (hard EM), so each Gaussian learns only from what it explains and
            the hypotheses stay apart; surprise (and validation) use the whole mixture. With
            the whole mixture in training, round seven's three Gaussians sat at one height
            (round eight: apart, and a hidden ball tracked again with ``stop_component``).
        learning_rate: Adam's (peak) learning rate.
        lr_schedule: ``"constant"`` or ``"cosine"`` (decays to 0 at ``trainer.max_steps``).
        training_frames: frames per training clip, recorded from the training batches.
    """

    ARCHITECTURE = ARCHITECTURE
    TRAINING_ONLY = ("learning_rate", "lr_schedule", "withhold", "withhold_frames",
                     "withhold_onsets", "hard_assignment")
    SURPRISE = ("the rectified excess surprisal of the seen object states (each term's negative "
                "log-likelihood less its entropy, where positive: the visibility, state and shape "
                "of every known object, and any newcomer's appearance)")

    def __init__(
        self,
        hidden_size: int = 128,
        message_size: int = 64,
        use_camera: bool = True,
        min_std: float = 0.01,
        components: int = 1,
        stop_component: bool = False,
        landing_component: bool = False,
        land_on_objects: bool = False,
        pivot_landing: bool = False,
        landing_change: bool = True,
        carry: str = "none",
        hold_still: bool = False,
        slowing: bool = False,
        falling_lands: bool = False,
        fall_gain: float = 0.0,
        shared_identity: bool = False,
        world_boxes: bool = False,
        withhold: float = 0.0,
        withhold_frames: int = 8,
        withhold_onsets: bool = False,
        hard_assignment: bool = False,
        learning_rate: float = 1e-3,
        lr_schedule: str = "constant",
        training_frames: int | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if hidden_size < 1 or message_size < 1:
            raise ValueError(f"hidden_size and message_size must be >= 1, got {hidden_size}, "
                             f"{message_size}")
        if min_std <= 0 or learning_rate <= 0:
            raise ValueError(f"min_std and learning_rate must be > 0, got {min_std}, "
                             f"{learning_rate}")
        if components < 1:
            raise ValueError(f"components must be >= 1 (Gaussians in the mixture over a "
                             f"slot's next state), got {components}")
        if stop_component and components < 2:
            raise ValueError(f"stop_component needs components >= 2 (one Gaussian for stopping, "
                             f"the others for moving on), got components={components}")
        if landing_component and components < 2 + stop_component:
            raise ValueError(f"landing_component needs components >= {2 + stop_component} (one "
                             f"Gaussian for landing{', one for stopping' if stop_component else ''}"
                             f", the others for moving on), got components={components}")
        if land_on_objects and not landing_component:
            raise ValueError("land_on_objects needs landing_component: true (it says where the "
                             "landing Gaussian lays an object)")
        if not landing_change and not landing_component:
            raise ValueError("landing_change: false needs landing_component: true (it is the "
                             "landing Gaussian's learned change that it leaves out)")
        if pivot_landing and (land_on_objects or not landing_component):
            raise ValueError("pivot_landing needs landing_component: true and land_on_objects: "
                             "false (it says, instead, where the landing Gaussian lays an "
                             f"object), got landing_component={landing_component}, "
                             f"land_on_objects={land_on_objects}")
        if not 0 <= withhold <= 1 or withhold_frames < 1:
            raise ValueError(f"withhold must be in [0, 1] (a share of each clip's objects) and "
                             f"withhold_frames >= 1, got {withhold}, {withhold_frames}")
        if carry not in CARRIES:
            raise ValueError(f"carry must be one of {CARRIES} (what a carrier passes on to the "
                             f"objects it carries), got {carry!r}")
        if falling_lands and not stop_component:
            raise ValueError("falling_lands needs stop_component: true (it leaves the stopping "
                             "Gaussian out for a falling object), got stop_component=false")
        if not 0 <= fall_gain <= MAX_MOVE:
            raise ValueError(f"fall_gain must be in [0, {MAX_MOVE}] (m a frame by which a falling "
                             f"object's downward move grows; 0.392 at 15 frames over 3 s), got "
                             f"{fall_gain}")
        if carry == "support" and not stop_component:
            raise ValueError("carry: support needs stop_component: true (it moves the stopping "
                             "Gaussian with what the object rests on), got stop_component=false")
        optimization.check_schedule(lr_schedule)
        hidden, message = hidden_size, message_size
        pair = PAIR_FEATURES + (WORLD_BOX_FEATURES if world_boxes else 0)
        self.message = PairNetwork(hidden, hidden, hidden, message, pair)
        self.update = nn.GRUCell(FEATURES + message + CAMERA_FEATURES, hidden)
        floor = FLOOR_FEATURES if landing_component else 0
        self.dynamics = mlp([hidden + message + CAMERA_FEATURES + floor, hidden, hidden,
                             self._dynamics_outputs(components)])
        self.occlusion = PairNetwork(hidden, 0, hidden, message, pair)
        self.visibility = mlp([hidden + message + VIEW + 3 + CAMERA_FEATURES, hidden, 1])
        self.carry = (PairNetwork(hidden, hidden, hidden, 1, pair)
                      if carry in ("velocity", "acceleration") else None)
        if self.carry is not None:
            nn.init.constant_(self.carry.out.bias, CARRY_START)
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
    def _inputs(self, frames: torch.Tensor, objects: TensorDictBase | None,
                camera: torch.Tensor | None) -> Observations:
        if objects is None:
            raise ValueError(
                "the object-state model (the positive control) reads each video's object "
                f"states (batch key 'objects', specs.objects_spec), but a batch of "
                f"{tuple(frames.shape[:2])} videos came without them; use the package's "
                "generated records (GENERATOR_VERSION 3 or later)")
        steps = frames.shape[1]
        if camera is None or not self.hparams.use_camera:
            camera = torch.tensor([0.0, 0.0, 0.4, 4.0, 90.0, -20.0], device=self.device)
            camera = camera.expand(frames.shape[0], steps, 6)
        return observe(objects.to(self.device), camera.to(self.device))

    # ----------------------------------------------------------------------------- core
    def _pairs(self, state: torch.Tensor, shape: torch.Tensor, seen_as: torch.Tensor
               ) -> torch.Tensor:
        """Pair features [B, S_i, S_j, PAIR_FEATURES (+ WORLD_BOX_FEATURES)] of slot j seen from
        slot i (``seen_as``: each slot's ``view``)."""
        def other_minus_self(values):
            return values[:, None, :] - values[:, :, None]

        def other(values):
            return values[:, None].expand(-1, slots, -1, -1)

        def own(values):
            return values[:, :, None].expand(-1, -1, slots, -1)

        def spanned(centres, halves):  # the share of i's box along each axis that j's spans
            return ((other(halves) + own(halves) - other_minus_self(centres).abs())
                    / (2 * own(halves)).clamp(min=1e-3)).clamp(0, 1)
        slots = state.shape[1]
        position, orientation, size = state[..., :3], state[..., 3:7], state[..., 7:10]
        centre, half = seen_as[..., 3:5], seen_as[..., 5:7]
        overlap = spanned(centre, half)
        boxes = []
        if self.hparams.world_boxes:
            extents = world_half_extents(state)
            bottom, top = position[..., 2] - extents[..., 2], position[..., 2] + extents[..., 2]
            boxes = [spanned(position, extents), (bottom[:, :, None] - top[:, None, :])[..., None]]
        return torch.cat([
            other_minus_self(position),
            other_minus_self(seen_as[..., :3]),
            other_minus_self(centre),
            other(size), own(size), other(half), own(half),
            overlap, overlap.prod(-1, keepdim=True),
            *boxes,
            other(orientation), other(shape),
        ], dim=-1)

    @staticmethod
    def _pair_weight(known: torch.Tensor) -> torch.Tensor:
        """1 for pairs (i, j) of known slots with j != i [B, S, S, 1]."""
        weight = known[:, None, :] & known[:, :, None]
        eye = torch.eye(known.shape[1], dtype=torch.bool, device=known.device)
        return (weight & ~eye).float()[..., None]

    def _messages(self, network: "PairNetwork", own: torch.Tensor, other: torch.Tensor | None,
                  pairs: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
        """Sum over the other known slots j of network(own_i, other_j, pair_ij) [B, S, M]."""
        return (network(own, other, pairs) * self._pair_weight(known)).sum(2)

    def rollout(self, observations: Observations, withheld: torch.Tensor | None = None
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
        terms = {key: [] for name in SLOT_TERMS + ("appear",)
                 for key in (name, f"{name}_entropy")}
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
                    terms[key].append(obs.state.new_zeros(
                        batch, *(() if key.startswith("appear") else (slots,))))
                probability.append(obs.state.new_zeros(batch, slots))
            else:
                predicted, step_terms, seen_probability, holding = self._predict(
                    hidden, belief, velocity, acceleration, shape, known, known & ~given_before,
                    still, pose, pose_features, obs, t)
                for key, value in step_terms.items():
                    terms[key].append(value)
                probability.append(seen_probability)
            predictions.append(predicted)
            # observe frame t: seen slots take what is seen, hidden ones their prediction or,
            # held, where they rest, moved on by what their support was seen to do beyond its
            # own prediction
            if holding is not None:
                hidden_now = (~given)[..., None]
                correction = ((obs.state[:, t, :, :3] - predicted[..., :3]) * given[..., None]
                              ).detach()
                carried = torch.einsum("bij,bjk->bik", holding.rests, correction) * hidden_now
                predicted = torch.where(holding.holds[..., None] & hidden_now, holding.state,
                                        predicted) + F.pad(carried, (0, STATE_SIZE - 3))
            previous = belief
            belief = torch.where(given[..., None], obs.state[:, t], predicted)
            # the last move: seen in both frames, what was seen; else what was predicted (a
            # reappearing object's jump from its predicted place is a correction, not a move)
            steady = (given & given_before)[..., None]
            move = torch.where(steady, belief, predicted)[..., :3] - previous[..., :3]
            moving = move * (known & ~new)[..., None].float()  # known before t
            acceleration, velocity = moving - velocity, moving
            still = torch.where(steady[..., 0], velocity[..., :2].norm(dim=-1) < MOVING, still)
            shape = torch.where(given[..., None], obs.shape[:, t], shape)
            known = known | visible
            given_before = given
            seen_as = view(belief, pose)
            features = torch.cat([belief, shape, (obs.fraction[:, t] * given)[..., None],
                                  seen_as, velocity, given[..., None].float()], dim=-1)
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

    def _predict(self, hidden, belief, velocity, acceleration, shape, known, unseen, still,
                 pose, pose_features, obs: Observations, t: int
                 ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor,
                            "Holding | None"]:
        """Frame t's predictions from the slots after frame t-1: the predicted states
        [B, S, 13] (the most probable component's mean: positions by inertia, the last frame's
        move repeated, plus a learned change, raised to rest on the floor where they would sink
        below it; a slot not given at t-1 (``unseen`` [B, S]) that ``Holding`` holds is held),
        the terms of what frame t shows (``rollout``), p(visible) [B, S] and, with ``carry:
        support`` or ``hold_still``, the ``Holding`` of every known slot (``still`` [B, S]: last
        seen not moving across the floor), else None."""
        pairs = self._pairs(belief, shape, view(belief, pose))
        message = self._messages(self.message, hidden, hidden, pairs, known)
        move = slowed(velocity, acceleration) if self.hparams.slowing else velocity
        falling = velocity[..., 2] < -MOVING  # [B, S]: its last move took it down
        if self.hparams.fall_gain:  # what falls, falls faster
            move = move - F.pad(falling[..., None] * self.hparams.fall_gain, (2, 0))
        if self.carry is not None:  # moves with at most one carrier: shares of 1 over self+others
            logit = self.carry(hidden, hidden, pairs).squeeze(-1)
            logit = logit.masked_fill(self._pair_weight(known)[..., 0] == 0, -math.inf)
            share = torch.softmax(F.pad(logit, (1, 0)), dim=-1)[..., 1:]  # own: logit 0
            passed = (velocity[:, None] - velocity[:, :, None]
                      if self.hparams.carry == "velocity" else acceleration[:, None])
            move = move + (share[..., None] * passed).sum(2)
        # bounded, so a hidden object's rollout cannot feed on itself and diverge
        inertia = F.pad(move.clamp(-MAX_MOVE, MAX_MOVE), (0, STATE_SIZE - 3))
        inputs = [hidden, message, pose_features]
        if self.hparams.landing_component:
            inputs.append(torch.stack([lowest_point(belief), lowest_point(belief + inertia)], -1))
        out = self.dynamics(torch.cat(inputs, dim=-1))
        components = self.hparams.components
        change, log_std, logits, shape_logits = out.split(
            [components * STATE_SIZE, components * STATE_SIZE,
             components if components > 1 else 0, SHAPES], -1)
        change = change.unflatten(-1, (components, STATE_SIZE))  # [B, S, K, 13]
        if not self.hparams.landing_change:  # the landing Gaussian: where inertia takes it, laid
            change = torch.cat([change[:, :, :-1], F.pad(change[:, :, -1:, 7:], (7, 0))], dim=2)
        log_std = log_std.unflatten(-1, (components, STATE_SIZE))
        if self.hparams.shared_identity:  # every hypothesis is about the object it is: size and
            identity = slice(7, STATE_SIZE)  # colour kept, under one learned spread for all
            change = torch.cat([change[..., :7], torch.zeros_like(change[..., identity])], -1)
            log_std = torch.cat([log_std[..., :7], log_std[..., :1, identity].expand(
                *log_std.shape[:-1], STATE_SIZE - 7)], -1)
        moved = ((belief[:, :, None] + self.inertia_kept * inertia[:, :, None])
                 + MAX_MOVE * torch.tanh(change / MAX_MOVE))
        means = on_or_above_floor(moved)
        if self.hparams.landing_component:  # it lands as the object it is: size and colour kept
            landing = torch.cat([moved[:, :, -1:, :7], belief[:, :, None, 7:]], dim=-1)
            if self.hparams.pivot_landing:
                landing = pivoted_down(on_or_above_floor(landing[:, :, 0]), belief, shape,
                                       known)[:, :, None]
            else:
                landing = lying_on_floor(landing)
            if self.hparams.land_on_objects:
                landing = on_what_is_below(landing[:, :, 0], belief, shape, known)[:, :, None]
            means = torch.cat([means[:, :, :-1], landing], dim=2)
        log_std = self.log_min_std + F.softplus(log_std - self.log_min_std)
        logits = logits if components > 1 else None
        if self.hparams.falling_lands:  # nothing stops in mid-air: it lands or falls on
            stopping = torch.arange(components, device=falling.device) == 0
            logits = logits.masked_fill(falling[..., None] & stopping, LEFT_OUT)
        top = (logits.argmax(-1) if logits is not None
               else torch.zeros_like(known, dtype=torch.long))

        def most_probable(means: torch.Tensor) -> torch.Tensor:
            return means.gather(2, top[..., None, None].expand(-1, -1, 1, STATE_SIZE))[:, :, 0]
        predicted = most_probable(means)
        holding = None
        if self.hparams.carry == "support" or self.hparams.hold_still:
            rests = belief.new_zeros(*known.shape, known.shape[1])
            carried = torch.zeros_like(belief)
            if self.hparams.carry == "support":  # what rests on a known object moves with it
                rests = resting_on(belief.detach(), shape, known)
                moves = ((predicted - belief)[..., :3] * known[..., None]).detach()
                carried = F.pad(torch.einsum("bij,bjk->bik", rests, moves), (0, STATE_SIZE - 3))
                means = torch.cat([on_or_above_floor(means[:, :, 0] + carried)[:, :, None],
                                   means[:, :, 1:]], dim=2)
                predicted = most_probable(means)
            holds = rests.sum(-1) > 0
            if self.hparams.hold_still:  # what was still when seen and lies on the floor
                holds = holds | (still & (lowest_point(belief) <= REST_TOLERANCE))
            holding = Holding(rests, holds, belief + carried)
            predicted = torch.where((unseen & holds)[..., None], holding.state, predicted)
        # visibility at t from where every known slot is predicted to be at t; no gradient
        # reaches the states from it: a hidden object's place is what the dynamics learned
        # from seen motion predicts, not one bent to explain why it is not seen (with it, a
        # cube at rest behind a container drifted into it, where the walls would hide it)
        placed = predicted.detach()
        seen_as = view(placed, pose)
        pairs = self._pairs(placed, shape, seen_as)
        occluders = self._messages(self.occlusion, hidden, None, pairs, known)
        geometry = seen_by_geometry(placed, shape, known, pose).clamp(0.02, 0.98)
        logit = self.visibility(torch.cat(
            [hidden, occluders, seen_as, placed[..., 7:10], pose_features], dim=-1)
        ).squeeze(-1) + self.geometry_weight * torch.logit(geometry)
        visible = obs.visible[:, t]
        seen, keep = visible.float(), known.float()
        terms = {}
        for name, (nll, entropy), weight in (
            ("visibility", bernoulli_nll(logit, seen), keep),
            ("state", mixture_nll(obs.state[:, t], means, log_std, logits,
                                  hard=self.training and self.hparams.hard_assignment),
             seen * keep),
            ("shape", categorical_nll(shape_logits, obs.shape[:, t]), seen * keep),
        ):
            terms[name], terms[f"{name}_entropy"] = nll * weight, entropy * weight
        terms.update(self._appearance(hidden, known, pose, visible & ~known, obs.state[:, t],
                                      obs.shape[:, t]))
        return predicted, terms, torch.sigmoid(logit) * keep, holding

    def _appearance(self, hidden: torch.Tensor, known: torch.Tensor, pose: torch.Tensor,
                    new: torch.Tensor, state: torch.Tensor, shape: torch.Tensor
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
        onsets = motion_onsets(observations) if self.hparams.withhold_onsets else None
        withheld = withheld_spans(observations.visible.shape, self.hparams.withhold,
                                  self.hparams.withhold_frames, observations.visible.device,
                                  onsets)
        out = self.rollout(observations, withheld)
        clips = frames.shape[0]
        terms = {name: out[name].sum() / clips  # the negative log-likelihood of the clips
                 for name in SLOT_TERMS + ("appear",)}
        terms["loss"] = sum(terms.values())
        self._check_finite(terms)
        self.log("train/loss", terms["loss"], prog_bar=True, batch_size=clips)
        for name, value in terms.items():
            if name != "loss":
                self.log(f"train/{name}", value, batch_size=clips)
        return terms["loss"]

    def configure_optimizers(self) -> dict:
        return optimization.adam(self.parameters(), self.hparams.learning_rate,
                                 self.hparams.lr_schedule,
                                 getattr(self._trainer, "max_steps", None))

    # ----------------------------------------------------------------------------- protocol
    @torch.no_grad()
    def surprise(self, frames: torch.Tensor, mask: torch.Tensor | None = None,
                 camera: torch.Tensor | None = None,
                 objects: TensorDictBase | None = None) -> torch.Tensor:
        """Per-frame surprise [B, T] (float32): the NLL of what is seen (class docstring)."""
        out = self.rollout(self._inputs(frames, objects, camera))
        return self._per_frame(out).float()

    @torch.no_grad()
    def expected_frames(self, frames: torch.Tensor, mask: torch.Tensor | None = None,
                        camera: torch.Tensor | None = None,
                        objects: TensorDictBase | None = None) -> torch.Tensor:
        """What the model expected [B, T, 3, H, W]: each known slot's expected state drawn as an
        ellipse of its colour where and as large as its box is seen, as opaque as the predicted
        probability that it is seen (frame 0: what is seen), nearer objects over farther."""
        observations = self._inputs(frames, objects, camera)
        out = self.rollout(observations)
        belief = torch.cat([out["belief"][:, :1], out["predicted"][:, 1:]], dim=1)
        opacity = torch.cat([observations.visible[:, :1].float(),
                             out["visible_probability"][:, 1:]], dim=1)
        return draw_ellipses(belief, opacity, observations.camera, frames.shape[2:4])

    @torch.no_grad()
    def trajectories(self, frames: torch.Tensor, mask: torch.Tensor | None = None,
                     camera: torch.Tensor | None = None,
                     objects: TensorDictBase | None = None) -> dict[str, torch.Tensor]:
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


def motion_onsets(observations: Observations) -> torch.Tensor:
    """The frames at which a seen object is set moving by another, bool [B, T, S]: seen at t-2,
    t-1 and t, it moved less than ``RESTING`` into t-1 and more than ``MOVING`` into t, and some
    other object seen at t-1 and t moved more than ``MOVING`` into t too (a container that
    carries it, a block that pushes it; a ball launched on its own is not one)."""
    def one_frame_later(values: torch.Tensor) -> torch.Tensor:
        return torch.cat([torch.zeros_like(values[:, :1]), values[:, :-1]], dim=1)
    seen = observations.visible
    position = observations.state[..., :3]
    move = (position - one_frame_later(position)).norm(dim=-1)
    seen_twice = seen & one_frame_later(seen)
    resting = seen_twice & (move < RESTING)
    moving = seen_twice & (move > MOVING)
    others_moving = moving.sum(-1, keepdim=True) - moving.long() > 0
    return moving & one_frame_later(resting) & others_moving


def withheld_spans(shape: torch.Size, share: float, longest: int, device: torch.device,
                   onsets: torch.Tensor | None = None) -> torch.Tensor | None:
    """Training's withheld observations, bool [B, T, S]: each (clip, slot) with probability
    ``share`` gets one span of 1 to ``longest`` frames, starting at a frame from 1 on, during
    which the model is not told what it sees. An object truly hidden in a clip has no target
    until it reappears, so without these spans a hidden object's rollout learns only from that
    frame, and drifts (a cube at rest behind a container: 0.2 m over nine frames). With
    ``onsets`` (``motion_onsets``), every slot that starts to move gets its span there
    instead, at least 2 frames long (up to ``longest``): the frame after the start is the one
    whose move only the other objects can explain. None if there is nothing to withhold."""
    if share <= 0 and onsets is None:
        return None
    batch, steps, slots = shape
    chosen = torch.rand(batch, 1, slots, device=device) < share
    start = torch.randint(1, max(steps, 2), (batch, 1, slots), device=device)
    length = torch.randint(1, longest + 1, (batch, 1, slots), device=device)
    if onsets is not None:
        starts_moving = onsets.any(1, keepdim=True)
        chosen = chosen | starts_moving
        start = torch.where(starts_moving, onsets.float().argmax(1, keepdim=True).long(), start)
        length = torch.where(starts_moving, length.clamp(min=min(2, longest)), length)
    time = torch.arange(steps, device=device)[None, :, None]
    return chosen & (time >= start) & (time < start + length)


class PairNetwork(nn.Module):
    """An MLP over [own_i, other_j, pair_ij] for every slot pair, with its first layer split
    by input: the slots' parts are computed once per slot, not once per pair (S times less)."""

    def __init__(self, own_size: int, other_size: int, hidden_size: int, output_size: int,
                 pair_size: int = PAIR_FEATURES):
        super().__init__()
        self.own = nn.Linear(own_size, hidden_size)
        self.other = nn.Linear(other_size, hidden_size, bias=False) if other_size else None
        self.pair = nn.Linear(pair_size, hidden_size, bias=False)
        self.out = nn.Linear(hidden_size, output_size)

    def forward(self, own: torch.Tensor, other: torch.Tensor | None, pairs: torch.Tensor
                ) -> torch.Tensor:
        """own [B, S, O], other [B, S, P] (or None), pairs [B, S, S, F] -> [B, S, S, out]."""
        first = self.own(own)[:, :, None] + self.pair(pairs)
        if self.other is not None:
            first = first + self.other(other)[:, None]
        return self.out(torch.relu(first))

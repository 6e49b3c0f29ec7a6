"""The positive control's run through a batch's frames (``SlotRollout.rollout``): per frame, the
predictions from the slots after the frame before, the likelihood terms of what the frame shows,
and the slots after it."""

from __future__ import annotations

from collections.abc import Collection, MutableMapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any, cast

import torch
import torch.nn.functional as F
from torch import nn

from voe_lightning.model.dynamics import camera_features
from voe_lightning.model.likelihood import (
    bernoulli_nll,
    categorical_nll,
    gaussian_nll,
    mixture_nll,
)
from voe_lightning.model.object_state.geometry import (
    VIEW,
    lowest_point,
    on_or_above_floor,
    seen_by_geometry,
    view,
)
from voe_lightning.model.object_state.masks import seen_box
from voe_lightning.model.object_state.mixture import (
    MAX_MOVE,
    Mixture,
    inertial_move,
    landing_mean,
)
from voe_lightning.model.object_state.pairs import (
    PairNetwork,
    SlotPairs,
    messages,
    pair_feature_size,
    pair_weight,
    pairwise,
    slot_pairs,
)
from voe_lightning.model.object_state.state import (
    IDENTITY,
    SHAPES,
    SLOT_TERMS,
    Observations,
    Slots,
    StateLayout,
    empty_slots,
)

if TYPE_CHECKING:
    from lightning.fabric.utilities.data import AttributeDict


def slot_feature_size(layout: StateLayout) -> int:
    """Per-slot features the recurrent core reads: the state, its shape (one-hot), its visible
    share, its view, its velocity and whether it is seen."""
    return layout.size + SHAPES + 1 + VIEW + layout.position_size + 1


#: Per-slot inputs of the dynamics with ``landing_component``: how high the lowest point of the
#: object's box is above the floor at its belief and where its inertia would take it.
FLOOR_FEATURES = 2


class SlotRollout:
    """The rollout of ``ObjectStateModel``, whose networks and hyperparameters it reads: declared
    below, built by the model."""

    layout: StateLayout
    message: PairNetwork
    update: nn.GRUCell
    dynamics: nn.Sequential
    appearance: nn.Sequential
    #: p(seen) with ``visibility_from: states``: in view, and covered by another slot.
    in_view: nn.Sequential
    cover: nn.Sequential
    #: p(seen) from memory (the other ``visibility_from``), and the sight lines' weight.
    occlusion: PairNetwork
    visibility: nn.Sequential
    geometry_weight: nn.Parameter
    log_min_std: float
    training: bool

    if TYPE_CHECKING:  # LightningModule's, as it declares it

        @property
        def hparams(self) -> AttributeDict | MutableMapping[Any, Any]: ...

    def rollout(
        self,
        observations: Observations,
        withheld: torch.Tensor | None = None,
        keys: Collection[str] | None = None,
    ) -> dict[str, torch.Tensor]:
        """Run the slots through a batch's frames. Returns, per frame and slot [B, T, S], the
        negative log-likelihood of the visibility, state and shape seen (0 where they do not
        apply) and the entropy of each prediction (``<term>_entropy``), ``appear`` and
        ``appear_entropy`` [B, T] (the appearance term), the beliefs after each frame and the
        states predicted for it (frame 0: none) [B, T, S, state], the predicted visibility
        probability [B, T, S], ``known`` [B, T, S] (seen at some frame <= t) and the slots'
        recurrent states [B, T, S, H].

        ``withheld`` (bool [B, T, S], training only): frames at which a known slot's
        observation is kept from the model, which rolls it forward as if it were hidden, while
        what it shows is still scored: a hidden object's rollout learns from targets
        (``withheld_spans``). ``keys``: only those outputs (training needs the terms alone)."""
        obs = observations
        slots = empty_slots(obs, self.hparams["hidden_size"], self.layout)
        given_before = slots.known  # what reached the model at the frame before (none before 0)
        pairs = None  # the slots' pair features, where the next prediction can read them
        frames = []
        for t in range(obs.visible.shape[1]):
            pose = obs.camera[:, t]
            pose_features = camera_features(pose)[:, None].expand(-1, slots.known.shape[1], -1)
            # what reaches the model: the seen slots, less a known one's withheld observation
            given = obs.visible[:, t]
            if withheld is not None:
                given = given & ~(withheld[:, t] & slots.known)
            if t == 0:
                predicted, terms, probability = self._nothing_predicted(obs, slots)
            else:
                predicted, terms, probability = self._predict(
                    slots, pose, pose_features, obs, t, pairs
                )
            slots, pairs = self._observe(slots, predicted, (given, given_before), obs, t)
            given_before = given
            frames.append(
                {
                    **terms,
                    "belief": slots.belief,
                    "predicted": predicted,
                    "visible_probability": probability,
                    "known": slots.known,
                    "hidden": slots.hidden,
                }
            )
        keys = frames[0] if keys is None else keys
        return {key: torch.stack([frame[key] for frame in frames], dim=1) for key in keys}

    @staticmethod
    def _nothing_predicted(
        obs: Observations, slots: Slots
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor]:
        """Frame 0's predictions, terms and p(visible): zeros, as nothing came before it."""
        batch, count = slots.known.shape
        terms = {
            key: obs.state.new_zeros(batch, *(() if name == "appear" else (count,)))
            for name in SLOT_TERMS + ("appear",)
            for key in (name, f"{name}_entropy")
        }
        return slots.belief, terms, obs.state.new_zeros(batch, count)

    def _observe(
        self,
        slots: Slots,
        predicted: torch.Tensor,
        givens: tuple[torch.Tensor, torch.Tensor],
        obs: Observations,
        t: int,
    ) -> tuple[Slots, SlotPairs | None]:
        """The slots after frame t: the slots given at t (and at t-1: ``givens``) take what is
        seen, the others their prediction; then each recurrent state steps. Also their pair
        features, which the next frame's prediction reads where no pose enters them (no
        ``projection``)."""
        given, given_before = givens
        visible = obs.visible[:, t]
        new = visible & ~slots.known
        belief = torch.where(given[..., None], obs.state[:, t], predicted)
        # the last move: seen in both frames, what was seen; else what was predicted (a
        # reappearing object's jump from its predicted place is a correction, not a move)
        steady = (given & given_before)[..., None]
        position = self.layout.position
        move = torch.where(steady, belief, predicted)[..., position] - slots.belief[..., position]
        velocity = move * (slots.known & ~new)[..., None].float()  # known before t
        known = slots.known | visible
        seen = Slots(
            hidden=slots.hidden,
            belief=belief,
            shape=torch.where(given[..., None], obs.shape[:, t], slots.shape),
            velocity=velocity,
            known=known,
        )
        hidden, pairs = self._recur(seen, given, obs.fraction[:, t], obs.camera[:, t])
        after = replace(seen, hidden=hidden * known[..., None], belief=belief * known[..., None])
        if self.hparams["projection"]:  # seen from the next frame's pose, the pairs differ
            return after, None
        # built from beliefs that differ from ``after``'s only in slots not yet known, whose
        # pairs weigh nothing
        return after, pairs

    def _view(self, state: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        """Where each slot is seen from ``pose`` [B, S, VIEW] (``view``: camera coordinates and
        image-plane box; perceived by masks or rgbd, the box its pixels span, ``seen_box``);
        zeros without ``projection``, where only the pose itself (each network's camera
        features) says where the camera is."""
        if not self.hparams["projection"]:
            return state.new_zeros(*state.shape[:-1], VIEW)
        if self.hparams["perception"] in ("masks", "rgbd"):
            return seen_box(state, self.layout)
        return view(state, pose)

    def _pairs(self, state: torch.Tensor, shape: torch.Tensor, seen_as: torch.Tensor) -> SlotPairs:
        """The slots' pair features (``slot_pairs``): with no ``projection``, no overlaps."""
        return slot_pairs(state, shape, seen_as, self.layout, boxes=self.hparams["projection"])

    def _recur(
        self, slots: Slots, given: torch.Tensor, fraction: torch.Tensor, pose: torch.Tensor
    ) -> tuple[torch.Tensor, SlotPairs]:
        """Each slot's next recurrent state [B, S, H], a GRU step on what it now believes, and
        the slots' pair features it read."""
        seen_as = self._view(slots.belief, pose)
        features = torch.cat(
            [
                slots.belief,
                slots.shape,
                (fraction * given)[..., None],
                seen_as,
                slots.velocity,
                given[..., None].float(),
            ],
            dim=-1,
        )
        pairs = self._pairs(slots.belief, slots.shape, seen_as)
        message = messages(self.message, slots.hidden, slots.hidden, pairs, slots.known)
        pose_features = camera_features(pose)[:, None].expand(-1, slots.known.shape[1], -1)
        step_input = torch.cat([features, message, pose_features], dim=-1)
        hidden = slots.hidden
        return self.update(step_input.flatten(0, 1), hidden.flatten(0, 1)).view_as(hidden), pairs

    def _predict(
        self,
        slots: Slots,
        pose: torch.Tensor,
        pose_features: torch.Tensor,
        obs: Observations,
        t: int,
        pairs: SlotPairs | None = None,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor]:
        """Frame t's predictions from the slots after frame t-1 (and their ``pairs``, where
        built already): the predicted states [B, S, state] (the most probable Gaussian's mean),
        the terms of what frame t shows (``rollout``) and p(visible) [B, S]."""
        h = self.hparams
        if pairs is None:
            pairs = self._pairs(slots.belief, slots.shape, self._view(slots.belief, pose))
        message = messages(self.message, slots.hidden, slots.hidden, pairs, slots.known)
        inertia = inertial_move(slots) if h["inertia"] else torch.zeros_like(slots.belief)
        mixture, shape_logits = self._mixture(slots, message, pose_features, inertia)
        predicted = mixture.most_probable()
        logit = self._visibility_logit(slots, predicted, pose, pose_features)
        hard = self.training and h["hard_assignment"]
        terms = slot_terms(slots, mixture, shape_logits, logit, obs, t, hard)
        visible = obs.visible[:, t]
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
        return predicted, terms, torch.sigmoid(logit) * slots.known.float()

    def _mixture(
        self,
        slots: Slots,
        message: torch.Tensor,
        pose_features: torch.Tensor,
        inertia: torch.Tensor,
    ) -> tuple[Mixture, torch.Tensor]:
        """The mixture over each slot's next state and its shape's logits [B, S, 7]: each mean
        the belief moved on by inertia plus a learned change, never below the floor; the last
        one laid down (``landing_mean``)."""
        belief, components = slots.belief, self.hparams["components"]
        change, log_std, logits, shape_logits = self._dynamics(
            slots, message, pose_features, inertia
        )
        moved = (belief + inertia)[:, :, None] + MAX_MOVE * torch.tanh(change / MAX_MOVE)
        means = on_or_above_floor(moved) if self.hparams["floor"] else moved
        if self.hparams["landing_component"]:
            landing = landing_mean(moved[:, :, -1], slots, self.hparams["pivot_landing"])
            means = torch.cat([means[:, :, :-1], landing[:, :, None]], dim=2)
        log_std = self.log_min_std + F.softplus(log_std - self.log_min_std)
        return Mixture(means, log_std, logits if components > 1 else None), shape_logits

    def _dynamics(
        self,
        slots: Slots,
        message: torch.Tensor,
        pose_features: torch.Tensor,
        inertia: torch.Tensor,
    ) -> tuple[torch.Tensor, ...]:
        """The dynamics' change and log-std [B, S, K, state], components' and shape's logits."""
        belief, components, size = slots.belief, self.hparams["components"], self.layout.size
        inputs = [slots.hidden, message, pose_features]
        if self.hparams["landing_component"]:  # how high the box's lowest point is, now and next
            inputs.append(torch.stack([lowest_point(belief), lowest_point(belief + inertia)], -1))
        change, log_std, logits, shape_logits = self.dynamics(torch.cat(inputs, dim=-1)).split(
            [
                components * size,
                components * size,
                components if components > 1 else 0,
                SHAPES,
            ],
            -1,
        )
        change = change.unflatten(-1, (components, size))  # [B, S, K, state]
        log_std = log_std.unflatten(-1, (components, size))
        if not self.hparams["landing_change"]:  # the landing Gaussian: where inertia takes it
            landing_identity = F.pad(change[:, :, -1:, IDENTITY], (IDENTITY.start, 0))
            change = torch.cat([change[:, :, :-1], landing_identity], dim=2)
        return change, log_std, logits, shape_logits

    def _visibility_logit(
        self, slots: Slots, predicted: torch.Tensor, pose: torch.Tensor, pose_features: torch.Tensor
    ) -> torch.Tensor:
        """The logit [B, S] that each slot is seen at t: a learned term from its view against
        the others' plus, with ``sight_lines``, sight lines to every known box at its predicted
        state (``seen_by_geometry``) times a learned weight. No gradient reaches the states from it: a hidden object's
        place is what the dynamics learned from seen motion predicts, not one bent to explain
        why it is not seen (with it, a cube behind a container drifted in, where walls hide it)."""
        placed = predicted.detach()
        seen_as = self._view(placed, pose)
        pairs = self._pairs(placed, slots.shape, seen_as)
        if self.hparams["visibility_from"] == "states":
            return self._composed_logit(placed, seen_as, pairs, slots.known, pose_features)
        occluders = messages(self.occlusion, slots.hidden, None, pairs, slots.known)
        extent = placed[..., self.layout.extent]
        learned: torch.Tensor = self.visibility(
            torch.cat([slots.hidden, occluders, seen_as, extent, pose_features], dim=-1)
        ).squeeze(-1)
        if not self.hparams["sight_lines"]:
            return learned
        geometry = seen_by_geometry(placed, slots.shape, slots.known, pose).clamp(0.02, 0.98)
        return learned + self.geometry_weight * torch.logit(geometry)

    def _composed_logit(
        self,
        placed: torch.Tensor,
        seen_as: torch.Tensor,
        pairs: SlotPairs,
        known: torch.Tensor,
        pose_features: torch.Tensor,
    ) -> torch.Tensor:
        """The logit [B, S] of p(seen) = p(in view) x the product over the other known slots j
        of 1 - p(j covers it), from the predicted states, views and pose alone: an object is
        seen unless it is out of view or something is in front of it."""
        own = torch.cat([placed, seen_as, pose_features], dim=-1)  # [B, S, ·]
        in_view = F.logsigmoid(self.in_view(own).squeeze(-1))
        # the cover network's first layer over [pair_ij, own_i], in its parts (SlotPairs)
        # mlp's first layer, which nn.Sequential's indexing types as any module
        first, size = cast(nn.Linear, self.cover[0]), pair_feature_size(self.layout)
        own_part, other_part, overlaps = pairs.project(first.weight[:, :size])
        own_part = own_part + F.linear(own, first.weight[:, size:], first.bias)
        per_pair = self.cover[1:](pairwise(own_part, other_part, overlaps))
        covered = F.softplus(per_pair.squeeze(-1))  # -log(1 - p(j covers i))
        log_seen = (in_view - (covered * pair_weight(known)[..., 0]).sum(-1)).clamp(max=-1e-6)
        return log_seen - torch.log(-torch.expm1(log_seen))

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
        share = known.float()[..., None]
        context = (hidden * share).sum(1) / share.sum(1).clamp(min=1)
        out = self.appearance(torch.cat([context, camera_features(pose)], dim=-1))
        size = self.layout.size
        logit, mean, log_std, shape_logits = out.split([1, size, size, SHAPES], -1)
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


def slot_terms(
    slots: Slots,
    mixture: Mixture,
    shape_logits: torch.Tensor,
    logit: torch.Tensor,
    obs: Observations,
    t: int,
    hard: bool,
) -> dict[str, torch.Tensor]:
    """Frame t's per-slot terms [B, S] and their entropies: each known slot's visibility and,
    seen, its state (the mixture; ``hard``: its best-explaining Gaussian) and shape."""
    seen, keep = obs.visible[:, t].float(), slots.known.float()
    state = mixture_nll(obs.state[:, t], mixture.means, mixture.log_std, mixture.logits, hard=hard)
    terms = {}
    for name, (nll, entropy), weight in (
        ("visibility", bernoulli_nll(logit, seen), keep),
        ("state", state, seen * keep),
        ("shape", categorical_nll(shape_logits, obs.shape[:, t]), seen * keep),
    ):
        terms[name], terms[f"{name}_entropy"] = nll * weight, entropy * weight
    return terms

"""PLATO's dynamics predictor: a slotted LSTM (one state per slot, shared weights) whose input
at each step comes from an interaction network over the slots' states, current codes and
attention summaries of their buffered earlier codes; it predicts every slot's next code."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

CAMERA_FEATURES = 8  # lookat xyz, distance, sin/cos azimuth, sin/cos elevation


def mlp(sizes: Sequence[int]) -> nn.Sequential:
    """Linear layers of ``sizes`` with ReLU between them (none after the last)."""
    layers: list[nn.Module] = []
    for index, (inputs, outputs) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(inputs, outputs))
        if index + 2 < len(sizes):
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def camera_features(camera: torch.Tensor) -> torch.Tensor:
    """Pose [..., 6] (lookat xyz, distance, azimuth and elevation in degrees) -> [..., 8] with
    the angles as sine and cosine, so 359 and 1 degrees are neighbours."""
    angles = torch.deg2rad(camera[..., 4:6].float())
    return torch.cat([camera[..., :4].float(), angles.sin(), angles.cos()], dim=-1)


class SlotDynamics(nn.Module):
    """Predicts each slot's next code from the current codes and the object buffer.

    Per step t and slot i, with LSTM state h_i, current code z_i and buffer summary b_i
    (attention of a query from h_i over slot i's codes z_i,<t):
    relation e_ij = MLP_rel([h_i, z_i, b_i, h_j, z_j, b_j]) summed over the other slots j seen
    by step t (a slot not yet seen neither sends nor receives messages, like a padding slot, so
    an object first seen later changes no earlier step);
    node input MLP_node([h_i, z_i, b_i, sum_j e_ij, camera]) -> LSTM -> h_i';
    prediction z_i,t+1 = z_i + Linear(h_i') (the change of code is predicted).

    With ``visibility``, a slot also predicts whether it is seen at t + 1 (a Bernoulli logit
    from its state and predicted code) and the spread of its code (a Gaussian's log-std, at least ``min_std``), and a context over
    the slots seen by t predicts whether a new object appears at t + 1 and its code
    (``rollout``). A known slot hidden at t (its mask empty) is rolled forward without a
    target: its input is the code predicted for it, not the code of its empty mask, and the
    node MLP reads whether it is seen. Its codes move on by inertia: the prediction is
    z_i + v_i + Linear(h_i'), v_i the last step's change of code (a slot seen at both steps:
    what was perceived; else what was predicted, so a reappearing object's jump from its
    predicted code is a correction, not a move), as the positive control's states do.

    Args:
        code_size: object code size.
        state_size: LSTM state per slot.
        relation_sizes, node_sizes: hidden layers of the relation and node MLPs.
        relation_size: output of the relation MLP (the summed message).
        interactions: build the relation MLP; False for a single slot (the object-free twin),
            which has nothing to interact with.
        use_camera: the node MLP also sees the camera pose of the frame being predicted.
        visibility: build the visibility, spread and appearance heads (``rollout``).
        min_std: floor of the predicted codes' standard deviations.
    """

    def __init__(
        self,
        code_size: int,
        state_size: int,
        relation_sizes: Sequence[int],
        node_sizes: Sequence[int],
        relation_size: int,
        interactions: bool = True,
        use_camera: bool = False,
        visibility: bool = False,
        min_std: float = 0.05,
    ) -> None:
        super().__init__()
        self.code_size, self.state_size = code_size, state_size
        self.use_camera, self.visibility = use_camera, visibility
        self.log_min_std = math.log(min_std)
        node_in = state_size + 2 * code_size + (1 if visibility else 0)
        self.relation = mlp([2 * node_in, *relation_sizes, relation_size]) if interactions else None
        node_inputs = node_in + (relation_size if interactions else 0)
        node_inputs += CAMERA_FEATURES if use_camera else 0
        self.node = nn.Sequential(mlp([node_inputs, *node_sizes, state_size]), nn.ReLU())
        self.query = nn.Linear(state_size, code_size)
        self.key = nn.Linear(code_size, code_size)
        self.cell = nn.LSTMCell(state_size, state_size)
        self.readout = nn.Linear(state_size, code_size)
        if visibility:
            self.spread = nn.Linear(state_size, code_size)
            self.seen_logit = mlp([state_size + code_size, state_size, 1])
            context = state_size + (CAMERA_FEATURES if use_camera else 0)
            self.appearance = mlp([context, state_size, 1 + 2 * code_size])

    def _buffer_summary(self, hidden: torch.Tensor, buffer: list[torch.Tensor]) -> torch.Tensor:
        """Attention of each slot's state over its own buffered codes [B, S, code_size]."""
        if not buffer:
            return hidden.new_zeros(*hidden.shape[:2], self.code_size)
        codes = torch.stack(buffer, dim=2)  # [B, S, t, C]
        scores = torch.einsum("bsc,bstc->bst", self.query(hidden), self.key(codes))
        weights = torch.softmax(scores / self.code_size**0.5, dim=-1)
        return torch.einsum("bst,bstc->bsc", weights, codes)

    def forward(
        self,
        codes: torch.Tensor,
        seen: torch.Tensor,
        camera: torch.Tensor | None = None,
        visible: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Codes [B, T, S, C] and whether each slot was seen by each step [B, T, S] (padding
        slots never) -> predictions [B, T, S, C], where prediction t is the code expected at
        t + 1 from codes <= t (and the camera pose of t + 1). With ``visibility``, ``visible``
        [B, T, S] (the slot's mask is not empty at t) is required: see the class docstring."""
        return self._run(codes, seen, camera, visible)[0]

    def rollout(
        self,
        codes: torch.Tensor,
        seen: torch.Tensor,
        visible: torch.Tensor,
        camera: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """The distributions a ``visibility`` model predicts at each step t for step t + 1:
        ``mean`` and ``log_std`` of each slot's code [B, T, S, C], its ``seen_logit``
        [B, T, S]; ``appear_logit`` [B, T] (some new object appears), ``newcomer_mean`` and
        ``newcomer_log_std`` [B, T, C] (its code)."""
        if not self.visibility:
            raise ValueError(
                "rollout needs the visibility heads: build SlotDynamics with visibility=True"
            )
        mean, hidden = self._run(codes, seen, camera, visible)
        context = (hidden * seen[..., None]).sum(2) / seen.sum(2, keepdim=True).clamp(min=1)
        if self.use_camera:
            assert camera is not None  # _run refuses None with use_camera
            poses = torch.cat([camera[:, 1:], camera[:, -1:]], dim=1)  # of the frame predicted
            context = torch.cat([context, camera_features(poses)], dim=-1)
        appear_logit, newcomer_mean, newcomer_log_std = self.appearance(context).split(
            [1, self.code_size, self.code_size], dim=-1
        )
        return {
            "mean": mean,
            "log_std": self._floored(self.spread(hidden)),
            "seen_logit": self.seen_logit(torch.cat([hidden, mean], -1)).squeeze(-1),
            "appear_logit": appear_logit.squeeze(-1),
            "newcomer_mean": newcomer_mean,
            "newcomer_log_std": self._floored(newcomer_log_std),
        }

    def _floored(self, log_std: torch.Tensor) -> torch.Tensor:
        """A log-std at least ``log(min_std)``, smoothly."""
        return self.log_min_std + F.softplus(log_std - self.log_min_std)

    def _run(
        self,
        codes: torch.Tensor,
        seen: torch.Tensor,
        camera: torch.Tensor | None,
        visible: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Step through time: predictions [B, T, S, C] and LSTM states [B, T, S, H]."""
        batch, steps, slots, _ = codes.shape
        if self.use_camera and camera is None:
            raise ValueError(
                "use_camera is set but no camera pose was given (batch key "
                "'camera', float [B, T, 6]); data without camera poses (IntPhys) "
                "needs a model trained with use_camera: false"
            )
        if self.visibility and visible is None:
            raise ValueError(
                "a visibility-aware SlotDynamics needs `visible` [B, T, S], "
                "whether each slot's mask is not empty at each frame"
            )
        hidden = codes.new_zeros(batch * slots, self.state_size)
        cell = torch.zeros_like(hidden)
        weight = seen.float()  # [B, T, S]
        pair_weight = weight[:, :, None, :] * weight[:, :, :, None]  # [B, T, S_i, S_j]
        pair_weight = pair_weight * (1 - torch.eye(slots, device=codes.device))  # j != i
        buffer: list[torch.Tensor] = []
        predictions: list[torch.Tensor] = []
        states: list[torch.Tensor] = []
        velocity = torch.zeros_like(codes[:, 0])
        for t in range(steps):
            code = codes[:, t]
            if self.visibility and t:  # a hidden slot goes on from what was predicted for it
                assert visible is not None  # refused above
                code = torch.where(visible[:, t, :, None], code, predictions[-1])
                steady = (visible[:, t] & visible[:, t - 1])[..., None]
                move = torch.where(steady, code, predictions[-1]) - buffer[-1]
                velocity = move * seen[:, t - 1, :, None]  # known before t
            state = hidden.view(batch, slots, -1)
            summary = self._buffer_summary(state, buffer)
            parts = [state, code, summary]
            if self.visibility:
                assert visible is not None  # refused above
                parts.append(visible[:, t, :, None].float())
            node = torch.cat(parts, dim=-1)  # [B, S, N]
            inputs = [node]
            if self.relation is not None:
                pairs = torch.cat(
                    [
                        node[:, :, None].expand(-1, -1, slots, -1),
                        node[:, None, :].expand(-1, slots, -1, -1),
                    ],
                    dim=-1,
                )
                messages = self.relation(pairs) * pair_weight[:, t, ..., None]  # [B, Si, Sj, R]
                inputs.append(messages.sum(dim=2))
            if self.use_camera:
                assert camera is not None  # refused above
                pose = camera[:, min(t + 1, steps - 1)]  # the pose of the frame predicted
                inputs.append(camera_features(pose)[:, None].expand(-1, slots, -1))
            step_input = self.node(torch.cat(inputs, dim=-1)).flatten(0, 1)
            hidden, cell = self.cell(step_input, (hidden, cell))
            change = self.readout(hidden).view(batch, slots, -1)
            predictions.append(code + velocity + change)
            states.append(hidden.view(batch, slots, -1))
            buffer.append(code)
        return torch.stack(predictions, dim=1), torch.stack(states, dim=1)

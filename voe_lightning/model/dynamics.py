"""PLATO's dynamics predictor: a slotted LSTM (one state per slot, shared weights) whose input
at each step comes from an interaction network over the slots' states, current codes and
attention summaries of their buffered earlier codes; it predicts every slot's next code."""

from __future__ import annotations

from collections.abc import Sequence

import torch
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

    Args:
        code_size: object code size.
        state_size: LSTM state per slot.
        relation_sizes, node_sizes: hidden layers of the relation and node MLPs.
        relation_size: output of the relation MLP (the summed message).
        interactions: build the relation MLP; False for a single slot (the object-free twin),
            which has nothing to interact with.
        use_camera: the node MLP also sees the camera pose of the frame being predicted.
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
    ) -> None:
        super().__init__()
        self.code_size, self.state_size = code_size, state_size
        self.use_camera = use_camera
        node_in = state_size + 2 * code_size
        self.relation = (mlp([2 * node_in, *relation_sizes, relation_size])
                         if interactions else None)
        node_inputs = node_in + (relation_size if interactions else 0)
        node_inputs += CAMERA_FEATURES if use_camera else 0
        self.node = nn.Sequential(mlp([node_inputs, *node_sizes, state_size]), nn.ReLU())
        self.query = nn.Linear(state_size, code_size)
        self.key = nn.Linear(code_size, code_size)
        self.cell = nn.LSTMCell(state_size, state_size)
        self.readout = nn.Linear(state_size, code_size)

    def _buffer_summary(self, hidden: torch.Tensor, buffer: list[torch.Tensor]) -> torch.Tensor:
        """Attention of each slot's state over its own buffered codes [B, S, code_size]."""
        if not buffer:
            return hidden.new_zeros(*hidden.shape[:2], self.code_size)
        codes = torch.stack(buffer, dim=2)  # [B, S, t, C]
        scores = torch.einsum("bsc,bstc->bst", self.query(hidden), self.key(codes))
        weights = torch.softmax(scores / self.code_size ** 0.5, dim=-1)
        return torch.einsum("bst,bstc->bsc", weights, codes)

    def forward(
        self, codes: torch.Tensor, seen: torch.Tensor, camera: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Codes [B, T, S, C] and whether each slot was seen by each step [B, T, S] (padding
        slots never) -> predictions [B, T, S, C], where prediction t is the code expected at
        t + 1 from codes <= t (and the camera pose of t + 1)."""
        batch, steps, slots, _ = codes.shape
        if self.use_camera and camera is None:
            raise ValueError("use_camera is set but no camera pose was given (batch key "
                             "'camera', float [B, T, 6]); data without camera poses (IntPhys) "
                             "needs a model trained with use_camera: false")
        hidden = codes.new_zeros(batch * slots, self.state_size)
        cell = torch.zeros_like(hidden)
        weight = seen.float()  # [B, T, S]
        pair_weight = weight[:, :, None, :] * weight[:, :, :, None]  # [B, T, S_i, S_j]
        pair_weight = pair_weight * (1 - torch.eye(slots, device=codes.device))  # j != i
        buffer: list[torch.Tensor] = []
        predictions = []
        for t in range(steps):
            state = hidden.view(batch, slots, -1)
            summary = self._buffer_summary(state, buffer)
            node = torch.cat([state, codes[:, t], summary], dim=-1)  # [B, S, N]
            inputs = [node]
            if self.relation is not None:
                pairs = torch.cat([node[:, :, None].expand(-1, -1, slots, -1),
                                   node[:, None, :].expand(-1, slots, -1, -1)], dim=-1)
                messages = self.relation(pairs) * pair_weight[:, t, ..., None]  # [B, Si, Sj, R]
                inputs.append(messages.sum(dim=2))
            if self.use_camera:
                pose = camera[:, min(t + 1, steps - 1)]  # the pose of the frame predicted
                inputs.append(camera_features(pose)[:, None].expand(-1, slots, -1))
            step_input = self.node(torch.cat(inputs, dim=-1)).flatten(0, 1)
            hidden, cell = self.cell(step_input, (hidden, cell))
            change = self.readout(hidden).view(batch, slots, -1)
            predictions.append(codes[:, t] + change)
            buffer.append(codes[:, t])
        return torch.stack(predictions, dim=1)

"""LRU memory invariants (docs/architecture.md §7): read weights are distributions, usage decays by
gamma, a closed write gate writes to the least-used slot(s), batch rows are independent, gradients
flow, and the controller sees the last read only when asked."""

import pytest
import torch

from voe_lightning.model.vrnn_lru.memory import HEAD_MIXINGS, LRUMemory, MemoryState

LATENT, SLOTS, UNITS, HEADS, CONTROLLER = 6, 5, 4, 3, 8


def make_memory(**kwargs) -> LRUMemory:
    torch.manual_seed(0)
    options = dict(
        num_slots=SLOTS, slot_size=UNITS, num_read_heads=HEADS, controller_size=CONTROLLER
    )
    options.update(kwargs)
    return LRUMemory(LATENT, **options)


def random_state(memory: LRUMemory, batch: int = 3) -> MemoryState:
    """A non-trivial state: random memory contents, usage and previous read weights."""
    generator = torch.Generator().manual_seed(1)
    previous = torch.rand(batch, memory.num_read_heads, memory.num_slots, generator=generator)
    previous = previous / previous.sum(-1, keepdim=True)
    return memory.initial_state(batch)._replace(
        memory=torch.randn(batch, memory.num_slots, memory.slot_size, generator=generator),
        usage=torch.rand(batch, memory.num_slots, generator=generator) * 3,
        read_weights=previous,
        mixed_read_weights=previous.mean(1),
        hidden=torch.randn(batch, memory.controller_size, generator=generator),
        cell=torch.randn(batch, memory.controller_size, generator=generator),
        read=torch.randn(batch, memory.read_size, generator=generator),
    )


def rollout(memory: LRUMemory, latents: torch.Tensor) -> list[torch.Tensor]:
    """Feed latents [B, T, LATENT] through read/write; return the reads of every step."""
    state = memory.initial_state(latents.shape[0])
    previous = torch.zeros_like(latents[:, 0])
    reads = []
    for t in range(latents.shape[1]):
        read = memory.read(state, previous)
        state = memory.write(state, read, latents[:, t])
        reads.append(read.read)
        previous = latents[:, t]
    return reads


@pytest.mark.parametrize("head_mixing", HEAD_MIXINGS)
def test_read_weights_sum_to_one(head_mixing):
    memory = make_memory(head_mixing=head_mixing)
    state = random_state(memory)
    read = memory.read(state, torch.randn(3, LATENT))
    assert read.weights.shape == (3, HEADS, SLOTS)
    assert (read.weights >= 0).all()
    torch.testing.assert_close(read.weights.sum(-1), torch.ones(3, HEADS))
    torch.testing.assert_close(read.mixed_weights.sum(-1), torch.ones(3))
    assert read.read.shape == (3, memory.read_size)
    expected_size = UNITS * HEADS if head_mixing == "concat" else UNITS
    assert memory.read_size == expected_size
    # The read is the weighted sum of slots under the (mixed) read weights.
    if head_mixing != "concat":
        torch.testing.assert_close(
            read.read, torch.einsum("bs,bsu->bu", read.mixed_weights, state.memory)
        )


def test_empty_memory_reads_uniformly_and_zero():
    memory = make_memory()
    read = memory.read(memory.initial_state(2), torch.randn(2, LATENT))
    torch.testing.assert_close(read.weights, torch.full((2, HEADS, SLOTS), 1.0 / SLOTS))
    torch.testing.assert_close(read.read, torch.zeros(2, UNITS))


def test_usage_decays_by_gamma():
    gamma = 0.8
    memory = make_memory(gamma=gamma)
    state = random_state(memory)
    read = memory.read(state, torch.randn(3, LATENT))
    write_weights, _ = memory.write_weights(state, read.hidden)
    new = memory.write(state, read, torch.randn(3, LATENT))
    torch.testing.assert_close(new.usage - read.weights.sum(1) - write_weights, gamma * state.usage)


def test_closed_write_gate_writes_to_least_used_slot():
    memory = make_memory()
    with torch.no_grad():
        memory.write_gate.weight.zero_()
        memory.write_gate.bias.fill_(-1e4)  # sigmoid(alpha) == 0
    state = random_state(memory)
    least_used = state.usage.argmin(-1)
    read = memory.read(state, torch.randn(3, LATENT))
    weights, one_hot = memory.write_weights(state, read.hidden)
    torch.testing.assert_close(weights, torch.nn.functional.one_hot(least_used, SLOTS).float())
    latent = torch.randn(3, LATENT)
    new = memory.write(state, read, latent)
    content = memory.write_projection(torch.cat([read.hidden, latent], -1))
    for row in range(3):
        slot = int(least_used[row])
        # The slot was cleared, then holds exactly the written content; others are untouched.
        torch.testing.assert_close(new.memory[row, slot], content[row])
        others = [i for i in range(SLOTS) if i != slot]
        torch.testing.assert_close(new.memory[row, others], state.memory[row, others])


@pytest.mark.parametrize("least_used_slots", [1, 2, SLOTS])
def test_least_used_weights_mark_n_slots_and_clear_only_the_least_used(least_used_slots):
    """Santoro et al.'s w^lu marks the n slots of smallest usage: a closed write gate writes the
    content into all n; only the single least-used slot is cleared first."""
    memory = make_memory(least_used_slots=least_used_slots)
    with torch.no_grad():
        memory.write_gate.weight.zero_()
        memory.write_gate.bias.fill_(-1e4)  # sigmoid(alpha) == 0: w^w = w^lu
    state = random_state(memory)
    by_usage = state.usage.argsort(-1)
    read = memory.read(state, torch.randn(3, LATENT))
    weights, cleared = memory.write_weights(state, read.hidden)
    assert weights.shape == cleared.shape == (3, SLOTS)
    assert (weights.sum(-1) == least_used_slots).all()
    for row in range(3):
        marked = set(by_usage[row, :least_used_slots].tolist())
        assert set(weights[row].nonzero().flatten().tolist()) == marked
    torch.testing.assert_close(cleared, torch.nn.functional.one_hot(by_usage[:, 0], SLOTS).float())
    latent = torch.randn(3, LATENT)
    new = memory.write(state, read, latent)
    content = memory.write_projection(torch.cat([read.hidden, latent], -1))
    for row in range(3):
        least, *others = by_usage[row, :least_used_slots].tolist()
        torch.testing.assert_close(new.memory[row, least], content[row])
        for slot in others:  # marked but not cleared: the content is added
            torch.testing.assert_close(
                new.memory[row, slot], state.memory[row, slot] + content[row]
            )


def test_least_used_slot_ties_go_to_the_lowest_index():
    memory = make_memory(least_used_slots=2)
    state = memory.initial_state(1)._replace(usage=torch.tensor([[1.0, 0.5, 0.5, 0.5, 2.0]]))
    read = memory.read(state, torch.zeros(1, LATENT))
    with torch.no_grad():
        memory.write_gate.bias.fill_(-1e4)
    weights, cleared = memory.write_weights(state, read.hidden)
    torch.testing.assert_close(weights.round(), torch.tensor([[0.0, 1.0, 1.0, 0.0, 0.0]]))
    torch.testing.assert_close(cleared, torch.tensor([[0.0, 1.0, 0.0, 0.0, 0.0]]))


def test_open_write_gate_writes_to_previously_read_slots():
    memory = make_memory()
    with torch.no_grad():
        memory.write_gate.weight.zero_()
        memory.write_gate.bias.fill_(1e4)  # sigmoid(alpha) == 1
    state = random_state(memory)
    read = memory.read(state, torch.randn(3, LATENT))
    weights, _ = memory.write_weights(state, read.hidden)
    torch.testing.assert_close(weights, state.mixed_read_weights)


def test_batch_rows_do_not_interact():
    memory = make_memory()
    latents = torch.randn(3, 5, LATENT, generator=torch.Generator().manual_seed(2))
    batched = torch.stack(rollout(memory, latents), 1)
    changed = latents.clone()
    changed[1] = torch.randn(5, LATENT)
    batched_changed = torch.stack(rollout(memory, changed), 1)
    torch.testing.assert_close(batched_changed[[0, 2]], batched[[0, 2]])
    assert not torch.allclose(batched_changed[1], batched[1])
    for row in range(3):
        alone = torch.stack(rollout(memory, latents[row : row + 1]), 1)
        torch.testing.assert_close(alone[0], batched[row], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    "options",
    [
        *({"head_mixing": mixing} for mixing in HEAD_MIXINGS),
        {"controller_sees_read": False, "least_used_slots": HEADS},  # the paper's reading
    ],
)
def test_gradients_reach_every_parameter(options):
    memory = make_memory(**options)
    latents = torch.randn(2, 4, LATENT, requires_grad=True)
    reads = rollout(memory, latents)
    torch.stack(reads).square().sum().backward()
    for name, parameter in memory.named_parameters():
        assert parameter.grad is not None, name
        assert parameter.grad.abs().sum() > 0, name
    assert latents.grad.abs().sum() > 0


def test_latent_write_content_writes_z_itself():
    memory = LRUMemory(UNITS, num_slots=SLOTS, slot_size=UNITS, write_content="latent")
    state = memory.initial_state(2)
    read = memory.read(state, torch.zeros(2, UNITS))
    latent = torch.randn(2, UNITS)
    weights, _ = memory.write_weights(state, read.hidden)
    new = memory.write(state, read, latent)
    torch.testing.assert_close(new.memory, weights.unsqueeze(-1) * latent.unsqueeze(1))


def test_controller_without_read_input():
    memory = make_memory(controller_sees_read=False)
    assert memory.controller.input_size == LATENT
    assert make_memory().controller.input_size == LATENT + UNITS
    # Without the read input, the controller's step (and so the read) ignores r_{t-1}.
    state = random_state(memory)
    latent = torch.randn(3, LATENT)
    other_read = state._replace(read=torch.randn_like(state.read))
    torch.testing.assert_close(
        memory.read(state, latent).hidden, memory.read(other_read, latent).hidden
    )
    seeing = make_memory()
    assert not torch.allclose(
        seeing.read(state, latent).hidden, seeing.read(other_read, latent).hidden
    )


def test_bad_choices_are_refused_naming_valid_ones():
    with pytest.raises(ValueError, match="'sum'.*controller, mean, concat"):
        make_memory(head_mixing="sum")
    with pytest.raises(ValueError, match="'key'.*projection, latent"):
        make_memory(write_content="key")
    with pytest.raises(ValueError, match="input_size.*slot_size"):
        make_memory(write_content="latent")
    with pytest.raises(ValueError, match="gamma"):
        make_memory(gamma=1.5)
    with pytest.raises(ValueError, match="num_slots"):
        make_memory(num_slots=0)
    for bad in (0, SLOTS + 1, 1.5, True):
        with pytest.raises(
            ValueError,
            match=f"least_used_slots must be an integer from 1 to the "
            f"number of memory slots \\({SLOTS}\\)",
        ):
            make_memory(least_used_slots=bad)
    with pytest.raises(TypeError, match="controller_sees_read must be True or False"):
        make_memory(controller_sees_read="no")

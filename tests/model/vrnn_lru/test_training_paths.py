"""The VRNN-LRU's training paths (issue 47): compiled (``compile: frame``) and the CUDA-graph
path's CPU fallback train like the eager path; a step syncs the host only when it reads its
terms back; a NaN is still named with its step; the KL and learning-rate schedules live on the
device; training clips held on the device come in the loader's order."""

import copy
import pickle

import pytest
import torch
from helpers.videos import moving_squares
from lightning.pytorch import Callback, Trainer
from tensordict import TensorDict
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils.data import DataLoader, SequentialSampler

from voe_lightning.datamodules import ConceptDataModule
from voe_lightning.datamodules.resident import ResidentBatches
from voe_lightning.model import VRNNLRUModel
from voe_lightning.model.optimization import adam
from voe_lightning.model.training_monitor import FiniteMonitor

B, T, H, W = 4, 5, 32, 32
TINY = dict(
    image_size=(H, W),
    latent_size=16,
    mlp_sizes=(32, 32),
    memory_slots=5,
    memory_slot_size=8,
    memory_read_heads=2,
    controller_size=16,
    encoder_blocks=3,
    encoder_channels=(8, 8, 16),
    encoder_mlp_size=32,
    learning_rate=1e-3,
    precision="float32",
)


def clips(count: int, seed: int = 0) -> torch.Tensor:
    return moving_squares(count, seed, frames=T, size=H)


def model(**overrides) -> VRNNLRUModel:
    torch.manual_seed(0)
    return VRNNLRUModel(**TINY, **overrides)


def trainer(steps: int, **overrides) -> Trainer:
    settings = dict(
        max_steps=steps,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        accelerator="cpu",
        gradient_clip_val=10.0,
    )
    return Trainer(**(settings | overrides))


def batches(videos: torch.Tensor) -> ResidentBatches:
    held = TensorDict(frames=videos, batch_size=[len(videos)])
    return ResidentBatches(held, SequentialSampler(range(len(videos))), B)


class LossRecorder(Callback):
    def __init__(self) -> None:
        self.losses: list[float] = []

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx) -> None:
        self.losses.append(float(outputs["loss"]))


def train(network: VRNNLRUModel, steps: int) -> list[float]:
    torch.manual_seed(1)  # the same noise on every path
    recorder = LossRecorder()
    trainer(steps, callbacks=[recorder]).fit(network, batches(clips(B * steps)))
    return recorder.losses


@pytest.mark.slow
def test_compiled_and_graph_fallback_training_follow_eager_over_100_steps():
    """Same weights, clips and noise: the compiled path's losses stay within 3% of eager's at
    every one of 100 steps (float sums in another order), then per-video surprise within 1%.
    On a CPU the CUDA-graph path is the compiled function run uncaptured, bit for bit."""
    paths = {"eager": model(compile="off"), "graphed": model(compile="frame", cuda_graph=True)}
    graphed = paths["graphed"]
    assert graphed.compiles and not graphed.captures
    losses = {name: train(network, 100) for name, network in paths.items()}
    assert losses["graphed"][0] == pytest.approx(losses["eager"][0], rel=1e-4)
    for step, (eager, compiled) in enumerate(zip(losses["eager"], losses["graphed"])):
        assert compiled == pytest.approx(eager, rel=0.03), step
    assert sum(losses["eager"][-10:]) < 0.8 * sum(losses["eager"][:10])  # it did train
    frames, noise = clips(B, seed=4), torch.randn(T, B, TINY["latent_size"])
    weight = torch.ones(())
    torch.testing.assert_close(
        graphed._training_loss(frames, noise, weight),
        graphed.training_terms(frames, noise, weight),
        rtol=0,
        atol=0,
    )
    probes = clips(B, seed=5)
    surprise = {name: network.eval().surprise(probes).sum(1) for name, network in paths.items()}
    torch.testing.assert_close(surprise["graphed"], surprise["eager"], rtol=0.01, atol=1e-3)


class SyncCounter(TorchDispatchMode):
    def __init__(self) -> None:
        super().__init__()
        self.syncs = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.syncs += func.__name__.split(".")[0] in ("_local_scalar_dense", "nonzero")
        return func(*args, **(kwargs or {}))


class PerStepSyncs(Callback):
    """Host syncs between each batch's start and end: forward, backward, clipping, Adam."""

    def __init__(self) -> None:
        self.syncs: dict[int, int] = {}

    def on_train_batch_start(self, trainer, module, batch, batch_idx) -> None:
        self.mode = SyncCounter()
        self.mode.__enter__()

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx) -> None:
        self.mode.__exit__(None, None, None)
        self.syncs[trainer.global_step] = self.mode.syncs


def test_a_training_step_syncs_the_host_only_when_it_reads_back():
    """With log_every_n_steps 4 over 9 steps the model reads its terms back (one sync, the
    finite check) after steps 4 and 8 and the last one; every other step syncs nothing."""
    counter = PerStepSyncs()
    trainer(9, log_every_n_steps=4, callbacks=[counter]).fit(model(), batches(clips(B * 9)))
    assert counter.syncs == {step: int(step in (4, 8, 9)) for step in range(1, 10)}


class PoisonAt(Callback):
    def __init__(self, step: int) -> None:
        self.step = step

    def on_train_batch_start(self, trainer, module, batch, batch_idx) -> None:
        if trainer.global_step == self.step:
            with torch.no_grad():
                module.decoder.logits[0].bias.fill_(float("nan"))


def test_a_nan_is_named_with_its_step_at_the_next_read_back():
    """A NaN first at global step 5 stops training at the read-back of step 7 (log every 4),
    naming step 5 and the term that broke, before step 7's update."""
    network, fit = model(), trainer(20, log_every_n_steps=4, callbacks=[PoisonAt(5)])
    with pytest.raises(FloatingPointError, match=r"global step 5: reconstruction=nan \(") as error:
        fit.fit(network, batches(clips(B * 20)))
    assert "kl=nan" not in str(error.value)
    assert fit.global_step == 7


def test_the_finite_monitor_keeps_the_first_bad_step_and_its_terms():
    monitor = FiniteMonitor(("a", "b"))
    monitor.check()  # nothing seen yet
    for step, terms in enumerate(
        [[1.0, 2.0], [3.0, 4.0], [float("inf"), 5.0], [float("nan"), 6.0]]
    ):
        monitor.update(torch.tensor(terms), torch.tensor(step))
    with pytest.raises(
        FloatingPointError, match=r"global step 2: a=inf \(all terms: \{'a': inf, 'b': 5.0\}"
    ):
        monitor.check()
    network = model()
    network._finite.update(torch.tensor([float("nan"), 1.0, 1.0]), torch.tensor(3))
    with pytest.raises(FloatingPointError, match="global step 3"):
        network.on_save_checkpoint({})  # no checkpoint of poisoned weights


def test_the_kl_warmup_weight_is_a_device_tensor_of_the_step():
    network = model(kl_warmup_steps=4)
    weights = [float(network.kl_weight_at(torch.tensor(step))) for step in range(6)]
    assert weights == [0.25, 0.5, 0.75, 1.0, 1.0, 1.0]
    assert float(model().kl_weight_at(torch.tensor(0))) == 1.0


def test_the_learning_rate_warms_up_linearly_as_a_tensor_for_fused_adam():
    parameters = [torch.nn.Parameter(torch.zeros(3))]
    optimization = adam(parameters, 1e-3, "constant", None, warmup_steps=4, fused=True)
    optimizer, schedule = optimization["optimizer"], optimization["lr_scheduler"]["scheduler"]
    assert optimizer.defaults["fused"] and isinstance(optimizer.param_groups[0]["lr"], torch.Tensor)
    rates = []
    for _ in range(6):
        rates.append(float(optimizer.param_groups[0]["lr"]))
        parameters[0].grad = torch.ones(3)
        optimizer.step()
        schedule.step()
    assert rates == pytest.approx([2.5e-4, 5e-4, 7.5e-4, 1e-3, 1e-3, 1e-3])
    cosine = adam(parameters, 1e-3, "cosine", 8, warmup_steps=2)["lr_scheduler"]["scheduler"]
    assert cosine.lr_lambdas[0](0) == pytest.approx(0.5) and cosine.lr_lambdas[0](
        4
    ) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="lr_warmup_steps must be >= 0, got -1"):
        model(lr_warmup_steps=-1)


def test_compile_settings_resolve_by_device_and_refuse_unknown_values():
    assert not model().compiles  # auto: off on a CPU
    assert model(compile="frame").compiles
    with pytest.raises(
        ValueError, match="unknown compile 'graph'; valid choices are: auto, off, frame"
    ):
        model(compile="graph")


def test_a_compiled_model_pickles_and_copies():
    """Compiled functions are dropped from a copy (ddp_spawn pickles the model) and made again
    where it first runs: the copy's surprise is the original's."""
    network = model(compile="frame").eval()
    probes = clips(2, seed=3)
    surprise = network.surprise(probes)
    for copied in (pickle.loads(pickle.dumps(network)), copy.deepcopy(network)):
        assert copied._compiled is None and copied.core._compiled_step is None
        torch.testing.assert_close(copied.surprise(probes), surprise, rtol=0, atol=0)


def test_resident_batches_follow_the_sampler_and_split_ranks(monkeypatch):
    videos = clips(10)
    order = [3, 1, 4, 0, 5, 9, 2, 6, 8, 7]
    resident = ResidentBatches(TensorDict(frames=videos, batch_size=[10]), order, 3)
    assert len(resident) == 3
    assert [batch["frames"].shape[0] for batch in resident] == [3, 3, 3]  # last one dropped
    first = next(iter(resident))["frames"]
    assert torch.equal(first, videos[[3, 1, 4]])
    monkeypatch.setattr(ResidentBatches, "_rank", lambda self: (1, 2))  # rank 1 of 2
    assert len(resident) == 1
    assert torch.equal(next(iter(resident))["frames"], videos[[0, 5, 9]])


def tiny_store(tmp_path) -> dict:
    """A ConceptDataModule's arguments for a tiny solidity store under ``tmp_path``."""
    return dict(
        concept="solidity",
        root=str(tmp_path / "data"),
        train_examples=4,
        val_pairs=1,
        test_pairs=1,
        generalization_pairs=1,
        batch_size=2,
        generate_workers=1,
        num_frames=5,
        height=32,
        width=32,
    )


def test_train_on_device_serves_the_loaders_clips_in_its_order(tmp_path):
    """The DataModule's resident batches hold exactly the frames its DataLoader would give."""
    arguments = tiny_store(tmp_path)
    standard, resident = (
        ConceptDataModule(**arguments),
        ConceptDataModule(**arguments, train_on_device=True),
    )
    for datamodule in (standard, resident):
        datamodule.prepare_data()
        datamodule.setup("fit")
    loaded = [batch["frames"] for batch in standard.train_dataloader()]
    held = [batch["frames"] for batch in resident.train_dataloader()]
    assert len(held) == len(loaded) == 4
    for a, b in zip(held, loaded):
        assert torch.equal(a, b)
    assert isinstance(standard.train_dataloader(), DataLoader)
    assert resident.train_dataloader().records is resident._resident  # decoded once
    assert list(resident._resident.keys()) == ["frames"]  # the frames alone by default
    assert isinstance(next(iter(resident.train_dataloader())), TensorDict)


def test_train_fields_hold_only_the_named_fields_in_the_loaders_order(tmp_path):
    """``train_fields``: the named fields of every training clip, decoded once and held in
    host memory, served in the DataLoader's order; an unknown field or none is refused."""
    arguments = tiny_store(tmp_path)
    standard = ConceptDataModule(**arguments)
    held = ConceptDataModule(**arguments, train_fields=["objects", "camera"])
    for datamodule in (standard, held):
        datamodule.prepare_data()
        datamodule.setup("fit")
    loaded = list(standard.train_dataloader())
    states = list(held.train_dataloader())
    assert len(states) == len(loaded) == 4
    for a, b in zip(states, loaded):
        assert sorted(a.keys()) == ["camera", "objects"]
        assert torch.equal(a["camera"], b["camera"])
        ids = a["objects", "visible_fraction"].shape[2]  # cut to the ids shown (shown_ids)
        assert ids < b["objects", "visible_fraction"].shape[2]
        for key, value in a["objects"].items():
            assert torch.equal(value, b["objects", key][:, :, :ids])
        assert not (b["objects", "visible_fraction"][:, :, ids:] > 0).any()
    assert held._resident.device == torch.device("cpu")
    with pytest.raises(ValueError, match="train_fields must name at least one"):
        ConceptDataModule(**arguments, train_fields=[])
    wrong = ConceptDataModule(**arguments, train_fields=["objects", "pose"])
    wrong.setup("fit")
    with pytest.raises(KeyError, match=r"\['pose'\].*they hold"):
        wrong.train_dataloader()

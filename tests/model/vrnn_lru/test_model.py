"""The VRNN-LRU model: shapes, gradients, the analytic KL, deterministic surprise, learning on a
tiny batch, the NaN guard, the probe interface, and bf16 autocast (all at 32x32, T=4-5)."""

import pytest
import torch
from lightning.pytorch import Trainer
from tensordict import TensorDict
from torch.distributions import Independent, Normal, kl_divergence
from torch.utils.data import DataLoader

from voe_lightning import specs
from voe_lightning.model import Decoder, Encoder, VRNNLRUModel, gaussian_kl, standard_normal_kl

B, T, H, W = 2, 4, 32, 32
TINY = dict(
    image_size=(H, W),
    latent_size=8,
    mlp_sizes=(16, 16),
    memory_slots=5,
    memory_slot_size=6,
    memory_read_heads=2,
    controller_size=12,
    encoder_blocks=3,
    encoder_channels=(4, 4, 8),
    encoder_mlp_size=20,
)


def tiny_model(**overrides) -> VRNNLRUModel:
    torch.manual_seed(0)
    return VRNNLRUModel(**{**TINY, **overrides})


def frames(batch=B, steps=T, seed=0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (batch, steps, H, W, 3), dtype=torch.uint8, generator=generator)


def test_encoder_decoder_shapes_fold_time():
    encoder = Encoder((H, W), num_blocks=3, channels=(4, 4, 8), mlp_size=20)
    decoder = Decoder(8, (H, W), num_blocks=3, channels=(4, 4, 8), mlp_size=20)
    assert encoder(torch.rand(B, T, 3, H, W)).shape == (B, T, 20)
    assert decoder(torch.randn(B, T, 8)).shape == (B, T, 3, H, W)
    assert Encoder((64, 48), num_blocks=4, channels=(4, 4, 8), mlp_size=5)(
        torch.rand(7, 3, 64, 48)
    ).shape == (7, 5)
    with pytest.raises(ValueError, match="divisible by 2\\*\\*num_blocks = 64"):
        Encoder((32, 32), num_blocks=6)


def test_forward_shapes_and_memory_trajectory():
    model = tiny_model()
    x = specs.to_model_input(frames())
    output, logits = model(x)
    assert logits.shape == (B, T, 3, H, W)
    for name in ("prior_mean", "prior_log_std", "posterior_mean", "posterior_log_std", "z"):
        assert getattr(output, name).shape == (B, T, 8), name
    assert output.kl.shape == (B, T)
    assert output.memory.shape == (B, T, 5 * 6)
    assert output.reads.shape == (B, T, 6)
    assert output.prior_log_std.abs().max() <= 10
    # The first step reads an empty memory, so its prior is the same for every video.
    torch.testing.assert_close(output.prior_mean[0, 0], output.prior_mean[1, 0])


def test_gradients_reach_every_parameter():
    model = tiny_model()
    terms = model._step(TensorDict(frames=frames(), batch_size=[B]))
    terms["loss"].backward()
    for name, parameter in model.named_parameters():
        assert parameter.grad is not None, name
        assert parameter.grad.abs().sum() > 0, name


def test_paper_memory_options_reach_the_memory_and_train():
    """configs/paper.yaml's reading: the controller sees z_{t-1} and its own state only, and
    w^lu marks as many least-used slots as there are read heads; shapes and gradients hold."""
    default, paper = tiny_model(), tiny_model(controller_sees_read=False, least_used_slots=2)
    assert default.core.memory.controller.input_size == 8 + 6  # z and the last read
    assert paper.core.memory.controller.input_size == 8  # z alone
    assert (default.core.memory.least_used_slots, paper.core.memory.least_used_slots) == (1, 2)
    assert paper.hparams.controller_sees_read is False and paper.hparams.least_used_slots == 2
    output, logits = paper(specs.to_model_input(frames()))
    assert output.kl.shape == (B, T) and logits.shape == (B, T, 3, H, W)
    paper._step(TensorDict(frames=frames(), batch_size=[B]))["loss"].backward()
    for name, parameter in paper.named_parameters():
        assert parameter.grad is not None and parameter.grad.abs().sum() > 0, name
    with pytest.raises(
        ValueError,
        match="least_used_slots must be an integer from 1 to the "
        "number of memory slots \\(5\\), got 6",
    ):
        tiny_model(least_used_slots=6)


def test_kl_matches_torch_distributions_and_is_non_negative():
    generator = torch.Generator().manual_seed(3)
    mean_q, log_std_q, mean_p, log_std_p = torch.randn(4, 3, 7, generator=generator)
    q = Independent(Normal(mean_q, log_std_q.exp()), 1)
    p = Independent(Normal(mean_p, log_std_p.exp()), 1)
    torch.testing.assert_close(
        gaussian_kl(mean_q, log_std_q, mean_p, log_std_p), kl_divergence(q, p)
    )
    standard = Independent(Normal(torch.zeros(3, 7), torch.ones(3, 7)), 1)
    torch.testing.assert_close(standard_normal_kl(mean_p, log_std_p), kl_divergence(p, standard))
    torch.testing.assert_close(gaussian_kl(mean_q, log_std_q, mean_q, log_std_q), torch.zeros(3))
    output, _ = tiny_model()(specs.to_model_input(frames()))
    assert (output.kl >= 0).all()
    expected = kl_divergence(
        Independent(Normal(output.posterior_mean, output.posterior_log_std.exp()), 1),
        Independent(Normal(output.prior_mean, output.prior_log_std.exp()), 1),
    )
    torch.testing.assert_close(output.kl, expected)


def test_surprise_is_deterministic_per_frame_kl():
    model = tiny_model()
    video = frames()
    surprise = model.surprise(video)
    assert surprise.shape == (B, T) and surprise.dtype == torch.float32
    assert not surprise.requires_grad
    torch.testing.assert_close(model.surprise(video), surprise, rtol=0, atol=0)
    # A row's surprise does not depend on the rest of the batch, up to float32 rounding: in
    # float32, as bf16 autocast (the default where the CPU has AVX512-BF16) may round a row
    # differently when oneDNN picks another kernel for another batch size.
    exact = tiny_model(precision="float32")
    torch.testing.assert_close(
        exact.surprise(video[1:]), exact.surprise(video)[1:], rtol=1e-5, atol=1e-5
    )
    # Deterministic mode equals a rollout fed with posterior means.
    expected = model.rollout(specs.to_model_input(video), deterministic=True).kl
    torch.testing.assert_close(surprise, expected)
    # Sampled surprise differs, and is reproducible with a seeded generator.
    sampled = model.surprise(video, deterministic=False, generator=torch.Generator().manual_seed(5))
    again = model.surprise(video, deterministic=False, generator=torch.Generator().manual_seed(5))
    torch.testing.assert_close(sampled, again, rtol=0, atol=0)
    assert not torch.allclose(sampled, surprise)


def test_loss_decreases_on_a_fixed_batch():
    model = tiny_model(learning_rate=3e-3)
    # Simple structured frames: a bright square moving right on a dark floor.
    video = torch.zeros(B, T, H, W, 3, dtype=torch.uint8)
    for t in range(T):
        video[:, t, 10:18, 4 + 5 * t : 12 + 5 * t] = 255
    batch = TensorDict(frames=video, batch_size=[B])
    optimizer = model.configure_optimizers()["optimizer"]
    torch.manual_seed(1)
    losses = []
    for _ in range(25):
        optimizer.zero_grad()
        loss = model._step(batch)["loss"]
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert sum(losses[-5:]) / 5 < 0.7 * sum(losses[:5]) / 5, losses


class _Clips(torch.utils.data.Dataset):
    def __init__(self, count: int):
        self.records = [
            TensorDict(frames=frames(1, seed=i)[0], batch_size=[]) for i in range(count)
        ]

    def __len__(self):
        return len(self.records)

    def __getitem__(self, index):
        return self.records[index]


def test_nan_loss_stops_training_naming_step_and_term(tmp_path):
    model = tiny_model()
    with torch.no_grad():
        model.decoder.logits[0].bias.fill_(float("nan"))  # only the reconstruction term breaks
    loader = DataLoader(_Clips(4), batch_size=2, collate_fn=torch.stack)
    trainer = Trainer(
        max_steps=2,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
        accelerator="cpu",
    )
    with pytest.raises(FloatingPointError, match="global step 0: reconstruction=nan \\(") as error:
        trainer.fit(model, loader)
    assert "kl=nan" not in str(error.value)


def test_training_logs_loss_terms(tmp_path):
    model = tiny_model()
    loader = DataLoader(_Clips(4), batch_size=2, collate_fn=torch.stack)
    trainer = Trainer(
        max_steps=2,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
        accelerator="cpu",
    )
    trainer.fit(model, loader)
    logged = trainer.callback_metrics
    for name in ("train/loss", "train/reconstruction", "train/kl", "train/prior_regularizer"):
        assert torch.isfinite(logged[name]), name
    torch.testing.assert_close(
        logged["train/loss"],
        logged["train/reconstruction"] + logged["train/kl"] + logged["train/prior_regularizer"],
    )


def test_probe_step_on_a_spec_batch():
    model = tiny_model()
    torch.manual_seed(4)
    batch = specs.probe_spec(T, H, W).expand(3).rand()
    result = model.probe_step(batch)
    assert set(result) == {
        "concept",
        "variant",
        "seed",
        "manipulation_frame",
        "first_difference",
        "inputs_differ",
        "surprise_consistent",
        "surprise_inconsistent",
    }
    for key in ("concept", "variant", "seed", "manipulation_frame"):
        assert torch.equal(result[key], batch[key])
    assert result["first_difference"].tolist() == [0, 0, 0]  # random videos differ at once
    assert result["inputs_differ"].tolist() == [0, 0, 0]
    assert result["surprise_consistent"].shape == (3, T)
    assert result["surprise_inconsistent"].shape == (3, T)
    torch.testing.assert_close(
        result["surprise_inconsistent"], model.surprise(batch["inconsistent", "frames"])
    )
    test_result = model.test_step(batch, 0)
    torch.testing.assert_close(test_result["surprise_consistent"], result["surprise_consistent"])


def test_expected_frames_and_trajectories():
    model = tiny_model()
    video = frames()
    expected = model.expected_frames(video)
    assert expected.shape == (B, T, 3, H, W)
    assert (expected >= 0).all() and (expected <= 1).all()
    # The first expectation precedes any observation: identical for every video.
    torch.testing.assert_close(expected[0, 0], expected[1, 0])
    trajectories = model.trajectories(video)
    assert trajectories["prior"].shape == (B, T, 16)
    assert trajectories["memory"].shape == (B, T, 30)


def test_bf16_autocast_keeps_kl_in_float32():
    model = tiny_model()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        terms = model._step(TensorDict(frames=frames(), batch_size=[B]))
        surprise = model.surprise(frames())
    assert surprise.dtype == torch.float32 and torch.isfinite(surprise).all()
    assert all(torch.isfinite(value) and value.dtype == torch.float32 for value in terms.values())
    terms["loss"].backward()


def test_bad_input_is_refused_clearly():
    model = tiny_model()
    with pytest.raises(ValueError, match="\\[B, T, 32, 32, 3\\].*\\(2, 4, 16, 16, 3\\)"):
        model.surprise(torch.zeros(2, 4, 16, 16, 3, dtype=torch.uint8))
    with pytest.raises(TypeError, match="uint8"):
        model.surprise(torch.zeros(2, 4, 32, 32, 3))
    with pytest.raises(ValueError, match="head_mixing 'max'"):
        tiny_model(head_mixing="max")
    with pytest.raises(ValueError, match="learning_rate"):
        tiny_model(learning_rate=0.0)


def test_hyperparameters_are_saved():
    model = tiny_model(learning_rate=1e-3)
    assert model.hparams.learning_rate == 1e-3
    assert model.hparams.latent_size == 8
    defaults = VRNNLRUModel()
    assert defaults.hparams.learning_rate == 5e-6
    assert defaults.core.latent_size == 256
    assert defaults.core.memory.num_slots == 15 and defaults.core.memory.slot_size == 100


def test_the_training_frame_count_is_recorded_for_the_benchmark_datamodules():
    """Issue 10 case 15: checkpoints carry training_frames, which IntPhys/Physical Concepts
    sample when not told otherwise; training on other clips than recorded says so."""
    model = tiny_model()
    assert model.hparams.training_frames is None
    model.on_train_batch_start({"frames": frames(steps=T)}, 0)
    assert model.hparams.training_frames == T
    with pytest.warns(
        UserWarning, match=rf"training_frames was {T}, the training clips have {T + 1}"
    ):
        model.on_train_batch_start({"frames": frames(steps=T + 1)}, 0)
    assert model.hparams.training_frames == T + 1


def test_kl_warmup_scales_only_the_training_kl(tmp_path):
    """With kl_warmup_steps=4 the loss of step s weighs KL by (s + 1) / 4; logged kl and
    surprise are never scaled."""
    model = tiny_model(kl_warmup_steps=4)
    assert model.kl_weight == pytest.approx(0.25)  # global step 0
    loader = DataLoader(_Clips(4), batch_size=2, collate_fn=torch.stack)
    trainer = Trainer(
        max_steps=2,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
        accelerator="cpu",
    )
    trainer.fit(model, loader)
    logged = trainer.callback_metrics  # the last step's terms: global step 1, weight 2 / 4
    torch.testing.assert_close(
        logged["train/loss"],
        logged["train/reconstruction"]
        + 0.5 * logged["train/kl"]
        + logged["train/prior_regularizer"],
    )
    assert tiny_model(kl_warmup_steps=0).kl_weight == 1.0
    model.eval()
    surprise = model.surprise(frames())
    model.hparams.kl_warmup_steps = 0
    torch.testing.assert_close(model.surprise(frames()), surprise)


def test_free_bits_clamp_each_latents_batch_mean_kl_in_the_loss_only():
    """With kl_free_bits the loss's KL term is sum_t,latents max(bits, batch-mean KL); the
    logged kl is the true KL, and latents under the floor get no KL gradient."""
    model = tiny_model()
    x = specs.to_model_input(frames())
    output, logits = model(x)
    per_latent = output.kl_per_latent()
    assert per_latent.shape == (B, T, 8)
    torch.testing.assert_close(per_latent.sum(-1), output.kl)
    batch_mean = per_latent.mean(dim=0)
    bits = batch_mean.median().item()  # about half the latents sit under the floor
    model.hparams.kl_free_bits = bits
    terms = model.loss_terms(x, output, logits)
    torch.testing.assert_close(terms["kl"], output.kl.sum(dim=1).mean())
    clamped = torch.where(batch_mean < bits, torch.full_like(batch_mean, bits), batch_mean).sum()
    assert clamped > terms["kl"]
    torch.testing.assert_close(
        terms["loss"], terms["reconstruction"] + clamped + terms["prior_regularizer"]
    )
    model.hparams.kl_free_bits = 1e6  # every latent under the floor: the KL term is constant
    terms = model.loss_terms(x, output, logits)
    torch.testing.assert_close(
        terms["loss"] - terms["reconstruction"] - terms["prior_regularizer"],
        torch.tensor(T * 8 * 1e6),
    )
    parameters = [p for p in model.parameters() if p.requires_grad]
    with_floor = torch.autograd.grad(
        terms["loss"], parameters, retain_graph=True, allow_unused=True
    )
    without_kl = torch.autograd.grad(
        terms["reconstruction"] + terms["prior_regularizer"], parameters, allow_unused=True
    )
    for a, b in zip(with_floor, without_kl, strict=True):
        if a is None or b is None:
            assert a is None and b is None
        else:
            torch.testing.assert_close(a, b)


def test_cosine_schedule_decays_to_zero_at_max_steps(tmp_path):
    model = tiny_model(lr_schedule="cosine", learning_rate=1e-3)
    loader = DataLoader(_Clips(4), batch_size=2, collate_fn=torch.stack)
    trainer = Trainer(
        max_steps=4,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
        accelerator="cpu",
    )
    trainer.fit(model, loader)
    schedule = trainer.lr_scheduler_configs[0]
    assert schedule.interval == "step"
    assert schedule.scheduler.get_last_lr()[0] == pytest.approx(0.0, abs=1e-12)  # step 4 of 4
    assert schedule.scheduler.lr_lambdas[0](2) == pytest.approx(0.5)  # half way: half the lr
    assert tiny_model().configure_optimizers().keys() == {"optimizer"}  # constant: no schedule


@pytest.mark.parametrize(
    "argument,value,message",
    [
        ("lr_schedule", "linear", "constant, cosine"),
        ("kl_warmup_steps", -1, "kl_warmup_steps must be >= 0"),
        ("kl_free_bits", -0.5, "kl_free_bits must be >= 0 nats, got -0.5"),
    ],
)
def test_bad_recipe_arguments_are_refused(argument, value, message):
    with pytest.raises(ValueError, match=message):
        tiny_model(**{argument: value})

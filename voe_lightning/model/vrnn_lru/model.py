"""The VRNN-LRU video model as a LightningModule: training loss (docs/architecture.md §7), surprise as
per-frame KL(posterior || prior) (§6), and the probe, expectation and trajectory views the
callbacks, reports and notebooks use."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, cast

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.model import optimization
from voe_lightning.model.base import SurpriseModel
from voe_lightning.model.training_monitor import FiniteMonitor
from voe_lightning.model.vrnn_lru.fast_path import COMPILE_MODES, PRECISIONS, bf16_is_fast
from voe_lightning.model.vrnn_lru.memory import LRUMemory
from voe_lightning.model.vrnn_lru.networks import Decoder, Encoder
from voe_lightning.model.vrnn_lru.vrnn import VRNNCore, VRNNOutput, standard_normal_kl

if TYPE_CHECKING:
    from lightning.pytorch.utilities.types import OptimizerConfig, OptimizerLRSchedulerConfig

#: A training step's loss and terms from (frames, noise, kl_weight), as a CUDA graph replays it.
TrainingTerms = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]

LOSS_TERMS = ("reconstruction", "kl", "prior_regularizer")
#: Constructor arguments that shape the parameters: a checkpoint must agree on all of them.
ARCHITECTURE = (
    "image_size",
    "latent_size",
    "mlp_sizes",
    "memory_slots",
    "memory_slot_size",
    "memory_read_heads",
    "controller_size",
    "head_mixing",
    "write_content",
    "controller_sees_read",
    "encoder_blocks",
    "encoder_channels",
    "encoder_mlp_size",
)


class VRNNLRUModel(SurpriseModel):
    """VRNN with an LRU external memory (Piloto et al. 2018 §4, Gemici et al. 2017).

    Defaults are the paper's sizes; ``configs/vrnn_quickstart.yaml`` shrinks them for a CPU.

    Args:
        image_size: (H, W) of the frames; both divisible by ``2**encoder_blocks``.
        latent_size: Gaussian latents per frame (paper: 256).
        mlp_sizes: hidden layers of the prior and posterior maps (paper: 512, 512).
        memory_slots, memory_slot_size, memory_read_heads, controller_size: LRU memory (paper:
            15 slots x 100 units, 3 read heads, 128-unit LSTM controller).
        usage_decay: gamma of the LRU usage (0.95).
        head_mixing, write_content, controller_sees_read, least_used_slots: the memory's open
            choices, see :class:`~voe_lightning.model.vrnn_lru.memory.LRUMemory`. The paper's reading
            (``configs/paper.yaml``): ``controller_sees_read=False`` (its LSTM sees the previous
            latent and its own state) and ``least_used_slots`` = the read heads (Santoro et
            al.'s n); the defaults (True, 1) keep earlier configs and checkpoints unchanged.
        encoder_blocks, encoder_channels, encoder_mlp_size: encoder (and mirrored decoder):
            stride-2 bottleneck blocks (paper: 6 of 64, 64, 128 channels) and MLP (paper: 500).
        prior_regularizer_weight: weight of sum_t KL(prior_t || N(0, I)) (paper: 1e-4).
        learning_rate, adam_betas: Adam (paper: lr 5e-6).
        lr_schedule: ``"constant"`` (the paper's) or ``"cosine"``: the learning rate decays
            per step along a half cosine to 0 at the Trainer's ``max_steps``.
        kl_warmup_steps: scale KL(posterior || prior) in the training loss from 0 up to 1 over
            this many steps (0, the paper's: no warm-up). Surprise is never scaled.
        kl_free_bits: free bits (Kingma et al. 2016), in nats per latent per frame: the training
            loss counts each latent's batch-mean KL at each frame as at least this much, so
            latents below it get no push toward the prior (0, the paper's: plain KL). The
            logged ``kl`` and surprise are the true KL.
        lr_warmup_steps: raise the learning rate linearly from 0 over this many steps (0, the
            paper's: none; large batches want it).
        compile: ``"frame"`` compiles (inductor) the recurrent core's one-frame step, called
            for each frame, and the encoder and decoder over all B x T frames at once;
            ``"off"`` runs them eagerly; ``"auto"`` (default) is ``frame`` on a GPU, ``off``
            elsewhere. Same maps; float sums in another order.
        cuda_graph: on a single CUDA device, capture the training loss's forward and backward
            as CUDA graphs (``torch.cuda.make_graphed_callables``) at the first training batch
            and replay them (thousands of kernel launches become two); elsewhere (a CPU, DDP)
            the same function runs uncaptured.
        channels_last: keep the encoder and decoder in NHWC layout, the fast layout of oneDNN
            and cuDNN (same float32 numbers up to summation order). False is the NCHW reference.
        precision: ``"auto"`` (default) runs the encoder and decoder under bf16 autocast where
            :func:`bf16_is_fast` says the device supports it, else leaves precision to the
            Trainer; ``"bf16"`` always does; ``"float32"`` disables autocast for the whole model
            (the reference numerics, also under a bf16 Trainer). The recurrent core, surprise
            and every loss term are float32 in all three.
        training_frames: frames per training clip, recorded from the training batches (leave it
            out); checkpoints carry it, so the benchmark DataModules sample as many frames.
    """

    ARCHITECTURE = ARCHITECTURE
    TRAINING_ONLY = (
        "learning_rate",
        "adam_betas",
        "lr_schedule",
        "kl_warmup_steps",
        "kl_free_bits",
        "lr_warmup_steps",
        "compile",
        "cuda_graph",
    )
    VALIDATION_METRIC = "val/kl"
    SURPRISE = "KL(posterior || prior)"
    #: Optimizer steps taken (a buffer, registered in ``__init__``).
    _steps: torch.Tensor

    def __init__(
        self,
        image_size: tuple[int, int] = (specs.HEIGHT, specs.WIDTH),
        latent_size: int = 256,
        mlp_sizes: Sequence[int] = (512, 512),
        memory_slots: int = 15,
        memory_slot_size: int = 100,
        memory_read_heads: int = 3,
        controller_size: int = 128,
        usage_decay: float = 0.95,
        head_mixing: str = "controller",
        write_content: str = "projection",
        controller_sees_read: bool = True,
        least_used_slots: int = 1,
        encoder_blocks: int = 6,
        encoder_channels: Sequence[int] = (64, 64, 128),
        encoder_mlp_size: int = 500,
        prior_regularizer_weight: float = 1e-4,
        learning_rate: float = 5e-6,
        adam_betas: tuple[float, float] = (0.9, 0.999),
        lr_schedule: str = "constant",
        kl_warmup_steps: int = 0,
        kl_free_bits: float = 0.0,
        lr_warmup_steps: int = 0,
        compile: str = "auto",
        cuda_graph: bool = True,
        channels_last: bool = True,
        precision: str = "auto",
        training_frames: int | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if precision not in PRECISIONS:
            raise ValueError(
                f"unknown precision {precision!r}; valid choices are: {', '.join(PRECISIONS)}"
            )
        if learning_rate <= 0:
            raise ValueError(f"learning_rate must be positive, got {learning_rate}")
        optimization.check_schedule(lr_schedule, lr_warmup_steps)
        if compile not in COMPILE_MODES:
            raise ValueError(
                f"unknown compile {compile!r}; valid choices are: {', '.join(COMPILE_MODES)}"
            )
        if kl_warmup_steps < 0:
            raise ValueError(f"kl_warmup_steps must be >= 0, got {kl_warmup_steps}")
        if kl_free_bits < 0:
            raise ValueError(f"kl_free_bits must be >= 0 nats, got {kl_free_bits}")
        if prior_regularizer_weight < 0:
            raise ValueError(
                f"prior_regularizer_weight must be non-negative, got {prior_regularizer_weight}"
            )
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.encoder = Encoder(
            self.image_size,
            encoder_blocks,
            encoder_channels,
            encoder_mlp_size,
            channels_last=channels_last,
        )
        self.decoder = Decoder(
            latent_size,
            self.image_size,
            encoder_blocks,
            encoder_channels,
            encoder_mlp_size,
            channels_last=channels_last,
        )
        memory = LRUMemory(
            latent_size,
            num_slots=memory_slots,
            slot_size=memory_slot_size,
            num_read_heads=memory_read_heads,
            controller_size=controller_size,
            gamma=usage_decay,
            head_mixing=head_mixing,
            write_content=write_content,
            controller_sees_read=controller_sees_read,
            least_used_slots=least_used_slots,
        )
        self.core = VRNNCore(self.encoder.output_size, latent_size, memory, mlp_sizes)
        # Compiled encoder and decoder, once resolved.
        self._compiled: dict[str, Callable[[torch.Tensor], torch.Tensor]] | None = None
        # (batch shape, captured training loss)
        self._graphed: tuple[torch.Size, TrainingTerms] | None = None
        self._finite = FiniteMonitor(LOSS_TERMS)  # the loss is their sum
        # Optimizer steps taken, on the device: the KL warm-up reads it without a host sync.
        self.register_buffer("_steps", torch.zeros((), dtype=torch.int64), persistent=False)

    def __getstate__(self) -> dict[str, Any]:
        # Compiled functions and captured graphs do not pickle (ddp_spawn, deepcopy): they are
        # made again where the copy first runs.
        return {**super().__getstate__(), "_compiled": None, "_graphed": None}

    # ----------------------------------------------------------------------------- inputs
    def _model_input(  # type: ignore[override]  # frames are always of this model's image_size
        self, frames: torch.Tensor
    ) -> torch.Tensor:
        """uint8 [B, T, H, W, 3] -> float [B, T, 3, H, W] on this module's device."""
        return super()._model_input(frames, self.image_size)

    # ----------------------------------------------------------------------------- model
    @property
    def uses_bf16(self) -> bool:
        """Whether the encoder and decoder run under bf16 autocast on the current device."""
        precision = self.hparams["precision"]
        return precision == "bf16" or (precision == "auto" and bf16_is_fast(self.device))

    def _autocast(self, networks: bool) -> contextlib.AbstractContextManager[Any]:
        """The precision context of the convolutional ``networks`` or of the recurrent core
        (no weight cache: each weight is cast once a pass anyway, and CUDA graphs need it off)."""
        if self.hparams["precision"] == "float32":
            return torch.autocast(self.device.type, enabled=False)
        if networks and self.uses_bf16:
            return torch.autocast(self.device.type, dtype=torch.bfloat16, cache_enabled=False)
        return contextlib.nullcontext()

    @property
    def compiles(self) -> bool:
        """Whether ``compile`` resolves to ``frame`` on the current device."""
        mode = self.hparams["compile"]
        return mode == "frame" or (mode == "auto" and self.device.type == "cuda")

    def _networks(self) -> dict[str, Callable[[torch.Tensor], torch.Tensor]]:
        """The encoder and decoder to call: compiled (once, on first use) when :attr:`compiles`."""
        if not self.compiles:
            return {"encoder": self.encoder, "decoder": self.decoder}
        if self._compiled is None:
            self.core.compile_step()
            self._compiled = {
                "encoder": torch.compile(self.encoder),
                "decoder": torch.compile(self.decoder),
            }
        return self._compiled

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Latents [B, T, latent_size] -> Bernoulli logits [B, T, 3, H, W] (bf16 on the fast path)."""
        with self._autocast(networks=True):
            return self._networks()["decoder"](z)

    def rollout(
        self,
        x: torch.Tensor,
        deterministic: bool = False,
        generator: torch.Generator | None = None,
        noise: torch.Tensor | None = None,
    ) -> VRNNOutput:
        """Encode all frames at once, then step the recurrent core through time (sampling with
        ``noise`` [T, B, latent_size] when given)."""
        with self._autocast(networks=True):
            embeddings = self._networks()["encoder"](x)
        with self._autocast(networks=False):
            output: VRNNOutput = self.core(
                embeddings.float(), deterministic=deterministic, generator=generator, noise=noise
            )
            return output

    def forward(
        self,
        x: torch.Tensor,
        deterministic: bool = False,
        generator: torch.Generator | None = None,
        noise: torch.Tensor | None = None,
    ) -> tuple[VRNNOutput, torch.Tensor]:
        """Model input [B, T, 3, H, W] in [0, 1] -> (rollout, Bernoulli logits [B, T, 3, H, W])."""
        output = self.rollout(x, deterministic=deterministic, generator=generator, noise=noise)
        return output, self.decode(output.z)

    def loss_terms(
        self,
        x: torch.Tensor,
        output: VRNNOutput,
        logits: torch.Tensor,
        kl_weight: torch.Tensor | float | None = None,
    ) -> dict[str, torch.Tensor]:
        """Per-sequence loss terms averaged over the batch (float32): reconstruction =
        sum_t,pixels BCE; kl = sum_t KL(post || prior); prior_regularizer = weight *
        sum_t KL(prior || N(0, I)); loss = their sum, kl times ``kl_weight`` (default: the
        warm-up's weight at this step; with free bits, the clamped KL of :meth:`kl_objective`
        in its place)."""
        kl_weight = self.kl_weight if kl_weight is None else kl_weight
        batch = x.shape[0]
        reconstruction = (
            F.binary_cross_entropy_with_logits(logits.float(), x.float(), reduction="sum") / batch
        )
        kl = output.kl.sum(dim=1).mean()
        prior_regularizer = self.hparams["prior_regularizer_weight"] * (
            standard_normal_kl(output.prior_mean, output.prior_log_std).sum(dim=1).mean()
        )
        return {
            "loss": (
                reconstruction + kl_weight * self.kl_objective(output, kl) + prior_regularizer
            ),
            "reconstruction": reconstruction,
            "kl": kl,
            "prior_regularizer": prior_regularizer,
        }

    def _step(self, batch: TensorDictBase | dict[str, Any]) -> dict[str, torch.Tensor]:
        """The named loss terms of a training batch at this step's KL weight, checked finite at
        once (a host sync): for training loops outside Lightning (tests, benchmarks)."""
        frames = self._checked_frames(self._frames_of(batch), self.image_size)
        noise = self.core.draw_noise(frames.shape[0], frames.shape[1], frames.device)
        values = self.training_terms(frames, noise, self.kl_weight_at(self._steps))
        terms = dict(zip(("loss", *LOSS_TERMS), values))
        self._check_finite(terms)
        return terms

    def training_terms(
        self, frames: torch.Tensor, noise: torch.Tensor, kl_weight: torch.Tensor
    ) -> torch.Tensor:
        """The training loss and its terms [loss, reconstruction, kl, prior_regularizer] of
        uint8 clips [B, T, H, W, 3] on this device, sampled with ``noise`` [T, B, latent_size]
        and the KL weighted by ``kl_weight`` (0-dim): a pure function of tensors with no host
        sync, which is what a CUDA graph captures."""
        x = specs.to_model_input(frames)
        output, logits = self(x, noise=noise)
        terms = self.loss_terms(x, output, logits, kl_weight)
        return torch.stack([terms[name] for name in ("loss", *LOSS_TERMS)])

    def _training_loss(
        self, frames: torch.Tensor, noise: torch.Tensor, kl_weight: torch.Tensor
    ) -> torch.Tensor:
        """:meth:`training_terms`, replayed from CUDA graphs when :attr:`captures` (captured at
        the first batch; a batch of another shape runs uncaptured)."""
        if not self.captures:
            return self.training_terms(frames, noise, kl_weight)
        if self._graphed is None:
            graphed = torch.cuda.make_graphed_callables(
                _TrainingTerms(self), (frames, noise, kl_weight), allow_unused_input=True
            )
            # The stub's Module | Callable: given a module, it returns it as a module.
            self._graphed = (frames.shape, cast(TrainingTerms, graphed))
        shape, graphed = self._graphed
        if frames.shape != shape:
            return self.training_terms(frames, noise, kl_weight)
        return graphed(frames, noise, kl_weight)

    @property
    def captures(self) -> bool:
        """Whether training replays CUDA graphs: ``cuda_graph`` on one CUDA device (under DDP
        the gradients' all-reduce hooks need the uncaptured step)."""
        single = self._trainer is None or self.trainer.world_size == 1
        return self.hparams["cuda_graph"] and self.device.type == "cuda" and single

    def training_step(self, batch: TensorDictBase, batch_idx: int) -> torch.Tensor:
        """One step without a host sync: noise drawn on the device, the terms checked there,
        and both read back (logged, checked) only every ``log_every_n_steps``."""
        frames = self._checked_frames(self._frames_of(batch), self.image_size)
        noise = self.core.draw_noise(frames.shape[0], frames.shape[1], frames.device)
        terms = self._training_loss(frames, noise, self.kl_weight_at(self._steps))
        self._finite.update(terms[1:], self._steps)
        self._steps += 1
        if self._read_back_now():
            self._finite.check()
            logged = terms.detach().clone()  # a captured graph's output is overwritten next step
            self.log_dict(
                {f"train/{name}": value for name, value in zip(("loss", *LOSS_TERMS), logged)},
                batch_size=frames.shape[0],
            )
        return terms[0]

    def _read_back_now(self) -> bool:
        """Whether this step logs and checks: every ``log_every_n_steps``, and the last one."""
        if self._trainer is None:
            return True
        # Set on the Trainer by its logger connector, so Lightning's types do not declare it.
        every, step = self.trainer.log_every_n_steps, self.global_step + 1  # type: ignore[attr-defined]
        return (every > 0 and step % every == 0) or step == self.trainer.max_steps

    def on_train_start(self) -> None:
        self._steps.fill_(self.global_step)  # a resumed run's warm-up goes on where it was

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        self._finite.check()  # no checkpoint of weights a NaN has already reached

    def on_train_end(self) -> None:
        self._finite.check()

    # ----------------------------------------------------------------------------- surprise
    def inputs_read(self) -> frozenset[str]:
        """Pixels alone (``surprise``)."""
        return frozenset()

    @torch.no_grad()
    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
        deterministic: bool = True,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """Per-frame surprise KL(posterior_t || prior_t) [B, T] (float32) of uint8 videos
        [B, T, H, W, 3]; deterministic (posterior means fed back) unless asked otherwise.
        Pixels alone: ``mask``, ``camera`` and ``objects`` are ignored."""
        x = self._model_input(frames)
        return self.rollout(x, deterministic=deterministic, generator=generator).kl

    @torch.no_grad()
    def latent_kl(self, frames: torch.Tensor) -> torch.Tensor:
        """KL(posterior_t || prior_t) per latent [B, T, latent_size] (float32) of uint8 videos
        [B, T, H, W, 3], deterministic rollout: surprise before the sum over latents. Latents
        near 0 in every frame carry nothing (posterior collapse; ``analyze latents``)."""
        return self.rollout(self._model_input(frames), deterministic=True).kl_per_latent()

    @torch.no_grad()
    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """What the model expected each frame to be given the previous ones (paper Figure 5):
        sigmoid(decoder(prior mean)) [B, T, 3, H, W], deterministic rollout (pixels alone)."""
        output = self.rollout(self._model_input(frames), deterministic=True)
        return torch.sigmoid(self.decode(output.prior_mean).float())

    @torch.no_grad()
    def trajectories(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> dict[str, torch.Tensor]:
        """Time courses for t-SNE (paper Appendix B): ``prior`` [B, T, 2Z] (mean then log-std)
        and ``memory`` [B, T, slots * units] after each step's write, deterministic rollout
        (pixels alone)."""
        output = self.rollout(self._model_input(frames), deterministic=True)
        return {
            "prior": torch.cat([output.prior_mean, output.prior_log_std], dim=-1),
            "memory": output.memory,
        }

    def kl_objective(self, output: VRNNOutput, kl: torch.Tensor) -> torch.Tensor:
        """The KL term the training loss minimizes: ``kl`` (per sequence, batch mean), or with
        free bits sum_t,latents max(free_bits, batch-mean KL of that latent at t)."""
        free_bits = self.hparams["kl_free_bits"]
        if not free_bits:
            return kl
        return output.kl_per_latent().mean(dim=0).clamp(min=free_bits).sum()

    def kl_weight_at(self, step: torch.Tensor) -> torch.Tensor:
        """Weight of the KL term at global ``step`` (a tensor, so the graph need not change):
        1, or the warm-up's ramp (step + 1) / kl_warmup_steps up to 1."""
        warmup = self.hparams["kl_warmup_steps"]
        if not warmup:
            return torch.ones((), device=step.device)
        weight: torch.Tensor = ((step + 1).float() / warmup).clamp(max=1.0)
        return weight

    @property
    def kl_weight(self) -> float:
        """:meth:`kl_weight_at` the trainer's global step, as a number."""
        return float(self.kl_weight_at(torch.tensor(self.global_step)))

    # ----------------------------------------------------------------------------- optimizer
    def configure_optimizers(self) -> OptimizerConfig | OptimizerLRSchedulerConfig:
        return optimization.adam(
            self.parameters(),
            self.hparams["learning_rate"],
            self.hparams["lr_schedule"],
            getattr(self._trainer, "max_steps", None),
            tuple(self.hparams["adam_betas"]),
            warmup_steps=self.hparams["lr_warmup_steps"],
            fused=True,
        )


class _TrainingTerms(torch.nn.Module):
    """:meth:`VRNNLRUModel.training_terms` as a module over the model's parameters, the form
    ``torch.cuda.make_graphed_callables`` captures (the model holds it outside its modules)."""

    def __init__(self, model: VRNNLRUModel) -> None:
        super().__init__()
        self.model = model

    def forward(
        self, frames: torch.Tensor, noise: torch.Tensor, kl_weight: torch.Tensor
    ) -> torch.Tensor:
        return self.model.training_terms(frames, noise, kl_weight)

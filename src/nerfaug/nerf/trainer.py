"""`Trainer`: fits a `NerfModel` to a growing set of views, one call to add views mid-run, and
checkpoints from which training resumes bit-identically on the CPU.

Every random number the trainer uses (pixels, sample jitter, occupancy-grid probes, random
backgrounds) comes from one `torch.Generator` it owns and checkpoints. Parameter initialisation
draws from the global RNG inside `fork_rng`, seeded from that generator, so the caller's global
RNG state is left as it was.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras, generate_rays
from nerfaug.data.views import Views
from nerfaug.device import autocast_dtype, resolve_device
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.model import NerfModel, total_loss
from nerfaug.nerf.registry import DEFAULT_FIELD, build_field
from nerfaug.progress import progress_bar

CHECKPOINT_FORMAT = 1
PROGRESS_EVERY = 10  # steps between updates of the progress display (and the train callback)


class TrainingDiverged(RuntimeError):
    """The loss became NaN or infinite; the model still holds the last good step's state."""

    def __init__(self, step: int, loss: float, checkpoint: Path | None = None):
        self.step, self.loss, self.checkpoint = step, loss, checkpoint
        message = f"training diverged at step {step}: loss = {loss}"
        message += f"; last good checkpoint kept at {checkpoint}" if checkpoint else "; no checkpoint was configured"
        super().__init__(message)


def exponential_lr(initial: float, final: float, step: int, decay_steps: int) -> float:
    """Learning rate decaying exponentially from `initial` (step 0) to `final` (step
    `decay_steps`), constant after (nerfstudio's ExponentialDecayScheduler without warm-up)."""
    fraction = min(max(step / max(decay_steps, 1), 0.0), 1.0)
    return math.exp(math.log(initial) * (1.0 - fraction) + math.log(final) * fraction)


def seeded_model(
    config: NerfConfig, generator: torch.Generator, background=(1.0, 1.0, 1.0), field: str | nn.Module = DEFAULT_FIELD
) -> NerfModel:
    """A fresh `NerfModel` on the CPU whose parameters are drawn from a seed that is `generator`'s
    next draw; the caller's global RNG state is left as it was. `field`: a name in
    `nerfaug.nerf.registry.FIELDS`, or a field module built by the caller."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(torch.randint(2**62, (1,), generator=generator)))
        built = build_field(config, field) if isinstance(field, str) else field
        return NerfModel(config, background, built)


def grown_views(current: Views, added: Views) -> Views:
    """The training views `current` followed by `added` (materialised), which must have their
    image size."""
    added = added.materialised()
    have, new = current.cameras, added.cameras
    if (new.width, new.height) != (have.width, have.height):
        raise ValueError(
            f"added views are {new.width}x{new.height}, the training views {have.width}x{have.height}; "
            "resize them first"
        )
    merged = Views.cat([current, added])
    if (current.alphas is None) != (added.alphas is None):
        merged.alphas = None  # mixed sources: fall back to the composited images only
    return merged


def sample_training_rays(
    cameras: Cameras,
    pixels: Tensor,
    alphas: Tensor | None,
    config: NerfConfig,
    background: Tensor,
    generator: torch.Generator,
) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
    """`config.optimiser.batch_size` rays drawn uniformly over all pixels of all training views.

    Args:
        cameras: the training views' cameras, on the training device.
        pixels: Tensor with shape (n_views * height * width, 3), their colours, view-major.
        alphas: Tensor with shape (n_views * height * width,), or None.
        background: Tensor with shape (3,), the colour the images were composited over.
        generator: the source of the draw (on the CPU or on the training device).

    Returns:
        origins, directions (B, 3), target colours (B, 3), and the background to render them
        over: (3,), (B, 3) (random backgrounds) or None (the model's last-sample colour).
    """
    per_view = cameras.width * cameras.height
    index = torch.randint(pixels.shape[0], (config.optimiser.batch_size,), generator=generator, device=generator.device)
    view, pixel = index // per_view, index % per_view
    origins, directions = generate_rays(cameras, view, pixel % cameras.width, pixel // cameras.width)
    index = index.to(pixels.device)
    target = pixels[index]
    ray_background = None if config.renderer.background_mode != "fixed" else background
    if config.renderer.random_background and alphas is not None:
        # Swap the stored background behind each pixel for a random colour the model must
        # learn to see through, so empty space cannot hide in the background colour.
        ray_background = torch.rand((index.shape[0], 3), generator=generator, device=generator.device).to(pixels.device)
        transparency = 1.0 - alphas[index, None]
        target = target + transparency * (ray_background - background)
    return origins, directions, target, ray_background


def psnr_from_mse(mse: float) -> float:
    """PSNR in dB of images in [0, 1] with mean squared error `mse`."""
    return -10.0 * math.log10(max(mse, 1e-10))


class Trainer:
    """Trains a NeRF on `views` and lets views be added at any step.

    Attributes:
        model: the `NerfModel` being trained.
        step: completed training steps.
        train_views: the current training views (materialised).
        history: one dict per completed step: {"step", "loss", "psnr", "losses"}: the loss, the PSNR
            of the batch's rgb, and each loss by name (`NerfModel.losses`: "rgb", and the
            proposal sampler's "distortion" and "interlevel"), whose sum is the loss.
        generator: the trainer's only source of randomness on the CPU (on a GPU, see
            `step_generator`).
        scaler: the float16 `GradScaler` when training under fp16 autocast (cuda), else None.
    """

    def __init__(
        self,
        views: Views,
        config: NerfConfig,
        seed: int = 0,
        device="cpu",
        background=(1.0, 1.0, 1.0),
        progress: bool = True,
        precision: str = "auto",
        field: str | nn.Module = DEFAULT_FIELD,
        compile: str | None = None,
    ):
        # device: "cpu", "cuda", "auto" (cuda when available); precision: "auto" (float32 on
        # every device), "fp32", or on cuda "fp16" or "bf16" (`nerfaug.device.autocast_dtype`).
        # field: a name in `nerfaug.nerf.registry.FIELDS`, built here from the seed, or a field
        # module built by the caller (a checkpoint then restores into the default field).
        # compile: a torch.compile backend ("inductor" on a GPU) for the field and the sampler's
        # networks, or None for the pure PyTorch path (the reference the CPU tests check).
        self.config, self.seed, self.device = config, seed, resolve_device(device)
        self._autocast = autocast_dtype(self.device, precision)
        # float16 gradients underflow without loss scaling; bfloat16 has float32's range.
        self.scaler = torch.amp.GradScaler("cuda") if self._autocast == torch.float16 else None
        # Drawing a step's ~10^6 jitter numbers on the CPU and copying them costs more than the
        # step on a GPU, so there they come from a generator on the device (see step_generator).
        self._device_generator = None if self.device.type == "cpu" else torch.Generator(device=self.device)
        self.background = tuple(float(c) for c in background)
        self.progress = progress
        self.generator = torch.Generator().manual_seed(seed)
        self._checkpoint_path: Path | None = None
        self.field_name = field if isinstance(field, str) else None
        self.model = seeded_model(config, self.generator, self.background, field).to(self.device)
        self.compile_backend = compile
        if compile is not None:
            self._compile_networks(compile)
        groups = self.model.param_groups()
        self.optimizer = torch.optim.Adam(
            [
                {
                    "params": params,
                    "lr": config.optimiser.field_lr if name == "field" else config.optimiser.lr,
                    "name": name,
                }
                for name, params in groups.items()
            ],
            eps=config.optimiser.adam_eps,
            fused=True,  # one kernel per step: much faster on a CPU too
        )
        self._initial_lrs = [group["lr"] for group in self.optimizer.param_groups]
        self.step = 0
        self.history: list[dict] = []
        self._set_views(views.materialised())

    def _compile_networks(self, backend: str) -> None:
        """Compile the field and the sampler's networks in place (`nn.Module.compile` keeps their
        parameters and state-dict keys, so checkpoints are unchanged). Measured on the CPU: the
        hash encoding 1.4-1.6x faster, a whole trial 1.17x, after 150 s of cold compilation
        (BENCHMARKS.md, "Engine variants"); on a GPU it is `benchmarks/bench_gpu.py --compile`'s
        to measure."""
        for module in [self.model.field, *getattr(self.model.sampler, "networks", [])]:
            module.compile(backend=backend)

    def step_generator(self) -> torch.Generator:
        """The generator the next step draws from. On the CPU the trainer's own `generator`
        (checkpointed with it). On another device a generator there, reseeded from (seed, step)
        before every step: deterministic per seed, and a checkpoint resumes exactly on any device
        without saving device RNG state."""
        if self._device_generator is None:
            return self.generator
        return self._device_generator.manual_seed((self.seed * 2**32 + self.step) % 2**63)

    def _set_views(self, views: Views) -> None:
        """Hold `views` on the device as flat pixel arrays for uniform sampling."""
        self.train_views = views
        self._cameras: Cameras = views.cameras.to(self.device)
        self._pixels: Tensor = views.images.reshape(-1, 3).to(self.device)
        self._alphas: Tensor | None = None if views.alphas is None else views.alphas.reshape(-1).to(self.device)

    def add_views(self, views: Views) -> None:
        """Train on `views` too, from the next step on. The model, the optimiser state and the
        step count are untouched. The new views must have the training views' image size."""
        self._set_views(grown_views(self.train_views, views))

    def sample_batch(self, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """A batch of rays drawn uniformly over all pixels of all training views, from
        `generator` (None: the trainer's `generator`).

        Returns:
            origins, directions (B, 3), target colours (B, 3), and the background to render
            them over: (3,), (B, 3) (random backgrounds) or None (the model's last-sample colour).
        """
        generator = self.generator if generator is None else generator
        return sample_training_rays(
            self._cameras, self._pixels, self._alphas, self.config, self.model.background, generator
        )

    def _set_learning_rates(self) -> None:
        for group, initial in zip(self.optimizer.param_groups, self._initial_lrs):
            group["lr"] = exponential_lr(
                initial, self.config.optimiser.lr_final, self.step, self.config.optimiser.lr_decay_steps
            )

    def train_step(self) -> dict:
        """Run one step. Returns its history entry. Raises TrainingDiverged on a NaN/inf loss
        (before any parameter is updated)."""
        self.model.train()
        generator = self.step_generator()
        self.model.before_step(self.step, generator)
        origins, directions, target, background = self.sample_batch(generator)
        if self._autocast is None:
            output = self.model(origins, directions, background, generator=generator)
        else:
            # Mixed precision where nerfacto uses it: the networks run in half precision; the
            # densities are float32 (`density_activation`), so weights, compositing and the
            # losses below stay float32.
            with torch.autocast(self.device.type, dtype=self._autocast):
                output = self.model(origins, directions, background, generator=generator)
        named = self.model.losses(output, target)
        loss = total_loss(named)
        # One transfer for every number the entry keeps (each float() of a GPU tensor waits for it).
        loss_value, *values = torch.stack([loss.detach(), *(v.detach() for v in named.values())]).tolist()
        if not math.isfinite(loss_value):
            path = self._checkpoint_path
            kept = path if path is not None and path.exists() else None
            raise TrainingDiverged(self.step, loss_value, kept)
        self.optimizer.zero_grad(set_to_none=True)
        self._set_learning_rates()
        if self.scaler is None:
            loss.backward()
            self.optimizer.step()
        else:  # skips the update when a float16 gradient overflowed, and lowers the scale
            self.scaler.scale(loss).backward()
            self.scaler.step(self.optimizer)
            self.scaler.update()
        self.step += 1
        losses = dict(zip(named, values))
        entry = {"step": self.step, "loss": loss_value, "psnr": psnr_from_mse(losses["rgb"]), "losses": losses}
        self.history.append(entry)
        return entry

    def train(
        self,
        until_step: int,
        checkpoint: str | Path | None = None,
        checkpoint_every: int = 1000,
        callback: Callable[[dict], None] | None = None,
    ) -> None:
        """Train until `self.step == until_step`.

        Args:
            until_step: the step to stop at (nothing happens if already there).
            checkpoint: if given, save here every `checkpoint_every` steps and at the end; on
                divergence this file keeps the last good state.
            callback: called every `PROGRESS_EVERY` steps and at the last with that step's
                history entry ({"step", "loss", "psnr"}), e.g. to show or log progress.

        Raises:
            TrainingDiverged: naming the step, the loss and the kept checkpoint.
        """
        self._checkpoint_path = Path(checkpoint) if checkpoint is not None else None
        if until_step < self.step:
            raise ValueError(f"already at step {self.step}, cannot train until step {until_step}")
        start = self.step
        progress = _progress_bar(self.progress)
        with progress:
            task = progress.add_task("training", total=until_step - start, loss=float("nan"), psnr=float("nan"))
            while self.step < until_step:
                entry = self.train_step()
                if self._checkpoint_path is not None and self.step % checkpoint_every == 0:
                    self.save_checkpoint(self._checkpoint_path)
                if self.step % PROGRESS_EVERY == 0 or self.step == until_step:
                    progress.update(task, completed=self.step - start, loss=entry["loss"], psnr=entry["psnr"])
                    if callback is not None:
                        callback(entry)
        if self._checkpoint_path is not None:
            self.save_checkpoint(self._checkpoint_path)

    def state_dict(self) -> dict:
        """Everything needed to resume: config, model (with occupancy grid), optimiser, step,
        history, RNG state and the training views."""
        views = self.train_views
        cameras = views.cameras
        return {
            "format": CHECKPOINT_FORMAT,
            "config": self.config.to_dict(),
            "field": self.field_name,
            "seed": self.seed,
            "background": list(self.background),
            "step": self.step,
            "history": self.history,
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "generator": self.generator.get_state(),
            **({"scaler": self.scaler.state_dict()} if self.scaler is not None else {}),
            "views": {
                "camera_to_world": cameras.camera_to_world,
                "fx": cameras.fx,
                "fy": cameras.fy,
                "cx": cameras.cx,
                "cy": cameras.cy,
                "width": cameras.width,
                "height": cameras.height,
                "images": views.images,
                "alphas": views.alphas,
                "names": list(views.names),
            },
        }

    def save_checkpoint(self, path: str | Path) -> Path:
        """Write the whole training state to `path` atomically (a reader sees the old file or
        the new one, never a partial one). Returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as handle:
                torch.save(self.state_dict(), handle)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    @classmethod
    def load_checkpoint(
        cls, path: str | Path | BinaryIO, device="cpu", progress: bool = True, precision: str = "auto"
    ) -> Trainer:
        """A trainer restored from `save_checkpoint` (on any device), from its file or its bytes
        (`io.BytesIO`: what a session checked); training continues exactly as it would have on the
        device it is restored to."""
        state = torch.load(path, map_location="cpu", weights_only=True)
        if state.get("format") != CHECKPOINT_FORMAT:
            named = f"{path}: " if isinstance(path, (str, Path)) else ""
            raise ValueError(f"{named}unsupported checkpoint format {state.get('format')!r}")
        v = state["views"]
        cameras = Cameras(v["camera_to_world"], v["fx"], v["fy"], v["cx"], v["cy"], v["width"], v["height"])
        views = Views(cameras, v["images"], list(v["names"]), v["alphas"])
        config = NerfConfig.from_dict(state["config"])
        trainer = cls(
            views,
            config,
            state["seed"],
            device,
            state["background"],
            progress,
            precision=precision,
            field=state.get("field") or DEFAULT_FIELD,
        )
        trainer.model.load_state_dict(state["model"])
        trainer.optimizer.load_state_dict(state["optimizer"])
        trainer.generator.set_state(state["generator"])
        if trainer.scaler is not None and "scaler" in state:
            trainer.scaler.load_state_dict(state["scaler"])
        trainer.step = state["step"]
        trainer.history = list(state["history"])
        return trainer


def _progress_bar(enabled: bool):
    """Training progress showing loss and PSNR (a live bar, or lines where stderr is not a terminal)."""
    return progress_bar(fields="loss {loss:.4f}  psnr {psnr:.2f} dB", enabled=enabled)

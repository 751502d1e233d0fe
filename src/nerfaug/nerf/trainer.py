"""`Trainer`: fits K `NerfModel`s (runs), each to its own growing set of views, in lockstep; a
single run is a batch of one. Views can be added to any run at any step, and checkpoints resume
bit-identically on the CPU.

Each run is computed exactly as it would be alone: its own model, optimiser, random source and
loss, stepped one after the other (`Run.step`), so a run's numbers do not depend on the runs that
share its batch, on any device, and a batch is the same engine as a run alone (no engine version
of its own). A run whose loss becomes NaN or infinite stops alone; the others train on.

Every random number a run uses (pixels, sample jitter, occupancy-grid probes, random
backgrounds) comes from one `torch.Generator` it owns and checkpoints. Parameter initialisation
draws from the global RNG inside `fork_rng`, seeded from that generator, so the caller's global
RNG state is left as it was.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable, Sequence
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

CHECKPOINT_FORMAT = 1  # a checkpoint of one run
BATCH_CHECKPOINT_FORMAT = 2  # of a batch of runs: the shared settings and each run's state under "runs"
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


def adam(model: NerfModel, config: NerfConfig) -> torch.optim.Adam:
    """A run's optimiser: Adam over the model's parameter groups ("field" at `field_lr`, the
    proposal networks at `lr`)."""
    return torch.optim.Adam(
        [
            {"params": params, "lr": initial_lr(config, name), "name": name}
            for name, params in model.param_groups().items()
        ],
        eps=config.optimiser.adam_eps,
        fused=True,  # one kernel per step: much faster on a CPU too
    )


def initial_lr(config: NerfConfig, group: str) -> float:
    """The learning rate of parameter group `group` at step 0."""
    return config.optimiser.field_lr if group == "field" else config.optimiser.lr


class Run:
    """One run of a `Trainer`: its seed, random source, model, optimiser, training views, history
    and failure. What selection, evaluation and a run's record read of a trained run (`model`,
    `train_views`, `history`, `device`).

    Attributes:
        model: the run's `NerfModel`.
        history: one dict per completed step: {"step", "loss", "psnr", "losses"}: the loss, the PSNR
            of the batch's rgb, and each loss by name (`NerfModel.losses`: "rgb", and the
            proposal sampler's "distortion" and "interlevel"), whose sum is the loss.
        generator: the run's only source of randomness on the CPU (on a GPU, see `step_generator`).
        scaler: the float16 `GradScaler` when training under fp16 autocast (cuda), else None.
        failure: why the run stopped training (`TrainingDiverged`), or None while it trains.
    """

    def __init__(self, views: Views, config: NerfConfig, seed: int, device: torch.device, trainer: Trainer, field):
        self.config, self.seed, self.device = config, seed, device
        # Drawing a step's ~10^6 jitter numbers on the CPU and copying them costs more than the
        # step on a GPU, so there they come from a generator on the device (see step_generator).
        self._device_generator = None if device.type == "cpu" else torch.Generator(device=device)
        self.generator = torch.Generator().manual_seed(seed)
        self.model = seeded_model(config, self.generator, trainer.background, field).to(device)
        if trainer.compile_backend is not None:
            compile_networks(self.model, trainer.compile_backend)
        self.optimizer = adam(self.model, config)
        # float16 gradients underflow without loss scaling; bfloat16 has float32's range.
        self.scaler = torch.amp.GradScaler("cuda") if trainer._autocast == torch.float16 else None
        self.history: list[dict] = []
        self.failure: TrainingDiverged | None = None
        self.set_views(views.materialised())

    def set_views(self, views: Views) -> None:
        """Hold `views` on the device as flat pixel arrays for uniform sampling."""
        self.train_views = views
        self.cameras: Cameras = views.cameras.to(self.device)
        self.pixels: Tensor = views.images.reshape(-1, 3).to(self.device)
        self.alphas: Tensor | None = None if views.alphas is None else views.alphas.reshape(-1).to(self.device)

    def step_generator(self, step: int) -> torch.Generator:
        """The generator step `step` draws from. On the CPU the run's own `generator`
        (checkpointed with it). On another device a generator there, reseeded from (seed, step)
        before every step: deterministic per seed, and a checkpoint resumes exactly on any device
        without saving device RNG state."""
        if self._device_generator is None:
            return self.generator
        return self._device_generator.manual_seed((self.seed * 2**32 + step) % 2**63)

    def sample_batch(self, generator: torch.Generator) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        """`sample_training_rays` over the run's training views, from `generator`."""
        return sample_training_rays(
            self.cameras, self.pixels, self.alphas, self.config, self.model.background, generator
        )

    def step(self, step: int, autocast: torch.dtype | None, checkpoint: Path | None) -> dict | None:
        """Train step `step` of this run alone. Returns its history entry, or None when its loss is
        NaN or infinite: then `failure` says so and no parameter is updated."""
        self.model.train()
        generator = self.step_generator(step)
        self.model.before_step(step, generator)
        origins, directions, target, background = self.sample_batch(generator)
        if autocast is None:
            output = self.model(origins, directions, background, generator=generator)
        else:
            # Mixed precision where nerfacto uses it: the networks run in half precision; the
            # densities are float32 (`density_activation`), so weights, compositing and the
            # losses below stay float32.
            with torch.autocast(self.device.type, dtype=autocast):
                output = self.model(origins, directions, background, generator=generator)
        named = self.model.losses(output, target)
        loss = total_loss(named)
        # One transfer for every number the entry keeps (each float() of a GPU tensor waits for it).
        loss_value, *values = torch.stack([loss.detach(), *(v.detach() for v in named.values())]).tolist()
        if not math.isfinite(loss_value):
            kept = checkpoint if checkpoint is not None and checkpoint.exists() else None
            self.failure = TrainingDiverged(step, loss_value, kept)
            return None
        self.optimizer.zero_grad(set_to_none=True)
        for group in self.optimizer.param_groups:
            group["lr"] = exponential_lr(
                initial_lr(self.config, group["name"]),
                self.config.optimiser.lr_final,
                step,
                self.config.optimiser.lr_decay_steps,
            )
        if self.scaler is None:
            loss.backward()
            self.optimizer.step()
        else:  # skips the update when a float16 gradient overflowed, and lowers the scale
            self.scaler.scale(loss).backward()
            self.scaler.step(self.optimizer)
            self.scaler.update()
        losses = dict(zip(named, values))
        entry = {"step": step + 1, "loss": loss_value, "psnr": psnr_from_mse(losses["rgb"]), "losses": losses}
        self.history.append(entry)
        return entry


def compile_networks(model: NerfModel, backend: str) -> None:
    """Compile a model's field and its sampler's networks in place (`nn.Module.compile` keeps their
    parameters and state-dict keys, so checkpoints are unchanged). Measured on the CPU: the hash
    encoding 1.4-1.6x faster, a whole trial 1.17x, after 150 s of cold compilation (BENCHMARKS.md,
    "Engine variants"); on a GPU it is `benchmarks/bench_gpu.py --compile`'s to measure."""
    for module in [model.field, *getattr(model.sampler, "networks", [])]:
        module.compile(backend=backend)


def _one_run(name: str, doc: str) -> property:
    """A single run's attribute, read (and set) on a trainer of one run: a batch refuses it."""

    def get(self):
        return getattr(self._only_run(name), name)

    def set_(self, value):
        setattr(self._only_run(name), name, value)

    return property(get, set_, doc=doc)


class Trainer:
    """Trains K NeRFs of one engine configuration in lockstep (K = 1: a run alone), each on its own
    views, and lets views be added to any run at any step.

    Args:
        views: the training views (one run), or each run's (a list: a batch of runs).
        seed: the run's seed, or each run's (a list, as long as `views`); run k's initial
            parameters and random numbers are those of `Trainer(views[k], config, seed[k])`.
        device: "cpu", "cuda", "auto" (cuda when available).
        precision: "auto" (float32 on every device), "fp32", or on cuda "fp16" or "bf16"
            (`nerfaug.device.autocast_dtype`).
        field: a name in `nerfaug.nerf.registry.FIELDS`, built here from each run's seed, or (one
            run) a field module built by the caller (a checkpoint then restores into the default
            field).
        compile: a torch.compile backend ("inductor" on a GPU) for each run's field and sampler
            networks, or None for the pure PyTorch path (the reference the CPU tests check).

    Attributes:
        runs: each run's `Run` (model, optimiser, views, history, failure).
        step: completed training steps (every run's).
        model, history, train_views, generator, seed, optimizer, scaler: the run's, on a trainer
            of one run.
    """

    model = _one_run("model", "The run's `NerfModel`.")
    history = _one_run("history", "The run's history (`Run.history`).")
    train_views = _one_run("train_views", "The run's current training views (materialised).")
    generator = _one_run("generator", "The run's random source on the CPU (`Run.generator`).")
    seed = _one_run("seed", "The run's seed.")
    optimizer = _one_run("optimizer", "The run's Adam.")
    scaler = _one_run("scaler", "The run's float16 `GradScaler` (fp16 autocast on cuda), else None.")

    def __init__(
        self,
        views: Views | Sequence[Views],
        config: NerfConfig,
        seed: int | Sequence[int] = 0,
        device="cpu",
        background=(1.0, 1.0, 1.0),
        progress: bool = True,
        precision: str = "auto",
        field: str | nn.Module = DEFAULT_FIELD,
        compile: str | None = None,
    ):
        batch = not isinstance(views, Views)
        all_views = list(views) if batch else [views]
        seeds = [int(s) for s in seed] if isinstance(seed, (list, tuple)) else [int(seed)]
        if not all_views or len(all_views) != len(seeds):
            raise ValueError(f"a batch of runs needs one seed per run: {len(all_views)} view sets, {len(seeds)} seeds")
        if len(seeds) > 1 and not isinstance(field, str):
            raise ValueError(
                f"a batch of {len(seeds)} runs builds each run's field by name; a field module is one run's"
            )
        self.config, self.device = config, resolve_device(device)
        self._autocast = autocast_dtype(self.device, precision)
        self.background = tuple(float(c) for c in background)
        self.progress = progress
        self._checkpoint_path: Path | None = None
        self.field_name = field if isinstance(field, str) else None
        self.compile_backend = compile
        self.step = 0
        self.runs = [Run(v, config, s, self.device, self, field) for v, s in zip(all_views, seeds)]

    def __len__(self) -> int:
        return len(self.runs)

    def _only_run(self, name: str) -> Run:
        if len(self.runs) != 1:
            raise AttributeError(f"a batch of {len(self.runs)} runs has no single {name}: read trainer.runs[k].{name}")
        return self.runs[0]

    def step_generator(self) -> torch.Generator:
        """The generator the next step of the run draws from (`Run.step_generator`); one run."""
        return self._only_run("step_generator").step_generator(self.step)

    def add_views(self, views: Views, run: int = 0) -> None:
        """Train run `run` on `views` too, from the next step on. The model, the optimiser state and
        the step count are untouched. The new views must have the training views' image size."""
        current = self.runs[run]
        current.set_views(grown_views(current.train_views, views))

    def sample_batch(self, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """A batch of the run's rays drawn uniformly over all pixels of all its training views, from
        `generator` (None: the run's `generator`); one run. Returns as `sample_training_rays`."""
        run = self._only_run("sample_batch")
        return run.sample_batch(run.generator if generator is None else generator)

    def train_step(self) -> dict:
        """Run one step of every run still training.

        Returns:
            One run: its history entry. A batch: {"step", "loss", "psnr"} (the means over the runs
            that trained) and "runs", each run's entry (None for a run that has diverged, now or
            before: its `failure` says when).

        Raises:
            TrainingDiverged: when no run is left training (a run alone: when its loss is NaN or
                infinite, before any parameter is updated).
        """
        entries = [
            run.step(self.step, self._autocast, self._checkpoint_path) if run.failure is None else None
            for run in self.runs
        ]
        done = [e for e in entries if e is not None]
        if not done:
            failure = next(run.failure for run in reversed(self.runs) if run.failure is not None)
            if len(self.runs) == 1:  # a run alone may be stepped again, from the state it kept
                self.runs[0].failure = None
            raise failure
        self.step += 1
        if len(self.runs) == 1:
            return done[0]
        mean = {key: sum(e[key] for e in done) / len(done) for key in ("loss", "psnr")}
        return {"step": self.step, **mean, "runs": entries}

    def failure(self, run: int) -> TrainingDiverged | None:
        """Why run `run` stopped training, or None while it trains."""
        return self.runs[run].failure

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
                entry (`train_step`'s: {"step", "loss", "psnr"}), e.g. to show or log progress.

        Raises:
            TrainingDiverged: naming the step, the loss and the kept checkpoint, when no run is
                left training.
        """
        self._checkpoint_path = Path(checkpoint) if checkpoint is not None else None
        if until_step < self.step:
            raise ValueError(f"already at step {self.step}, cannot train until step {until_step}")
        start = self.step
        label = "training" if len(self.runs) == 1 else f"training {len(self.runs)} runs"
        with _progress_bar(self.progress) as progress:
            task = progress.add_task(label, total=until_step - start, loss=float("nan"), psnr=float("nan"))
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
        """Everything needed to resume: config, each run's model (with occupancy grid), optimiser,
        history, RNG state and training views, and the step. One run: its state beside the
        config (`CHECKPOINT_FORMAT`); a batch: each run's under "runs" (`BATCH_CHECKPOINT_FORMAT`)."""
        shared = {"config": self.config.to_dict(), "field": self.field_name}
        if len(self.runs) == 1:
            run = _run_state(self.runs[0])
            return {"format": CHECKPOINT_FORMAT, **shared, "seed": run.pop("seed"), **self._common(), **run}
        runs = [_run_state(run) for run in self.runs]
        return {"format": BATCH_CHECKPOINT_FORMAT, **shared, **self._common(), "runs": runs}

    def _common(self) -> dict:
        return {"background": list(self.background), "step": self.step}

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
        cls,
        path: str | Path | BinaryIO,
        device="cpu",
        progress: bool = True,
        precision: str = "auto",
        compile: str | None = None,
    ) -> Trainer:
        """A trainer restored from `save_checkpoint` (on any device), from its file or its bytes
        (`io.BytesIO`: what a session checked); training continues exactly as it would have on the
        device it is restored to."""
        state = torch.load(path, map_location="cpu", weights_only=True)
        if state.get("format") not in (CHECKPOINT_FORMAT, BATCH_CHECKPOINT_FORMAT):
            named = f"{path}: " if isinstance(path, (str, Path)) else ""
            raise ValueError(f"{named}unsupported checkpoint format {state.get('format')!r}")
        runs = state["runs"] if state["format"] == BATCH_CHECKPOINT_FORMAT else [state]
        views = [_views_of(run["views"]) for run in runs]
        trainer = cls(
            views if state["format"] == BATCH_CHECKPOINT_FORMAT else views[0],
            NerfConfig.from_dict(state["config"]),
            [run["seed"] for run in runs],
            device,
            state["background"],
            progress,
            precision=precision,
            field=state.get("field") or DEFAULT_FIELD,
            compile=compile,
        )
        for run, saved in zip(trainer.runs, runs):
            run.model.load_state_dict(saved["model"])
            run.optimizer.load_state_dict(saved["optimizer"])
            run.generator.set_state(saved["generator"])
            if run.scaler is not None and "scaler" in saved:
                run.scaler.load_state_dict(saved["scaler"])
            run.history = list(saved["history"])
            if saved.get("failure") is not None:
                step, loss = saved["failure"]
                run.failure = TrainingDiverged(int(step), float(loss))
        trainer.step = state["step"]
        return trainer


def _run_state(run: Run) -> dict:
    """One run's part of a checkpoint."""
    views, cameras = run.train_views, run.train_views.cameras
    failure = None if run.failure is None else [run.failure.step, run.failure.loss]
    return {
        "seed": run.seed,
        "history": run.history,
        "model": run.model.state_dict(),
        "optimizer": run.optimizer.state_dict(),
        "generator": run.generator.get_state(),
        **({"scaler": run.scaler.state_dict()} if run.scaler is not None else {}),
        **({"failure": failure} if failure is not None else {}),
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


def _views_of(saved: dict) -> Views:
    cameras = Cameras(
        saved["camera_to_world"], saved["fx"], saved["fy"], saved["cx"], saved["cy"], saved["width"], saved["height"]
    )
    return Views(cameras, saved["images"], list(saved["names"]), saved["alphas"])


def _progress_bar(enabled: bool):
    """Training progress showing loss and PSNR (a live bar, or lines where stderr is not a terminal)."""
    return progress_bar(fields="loss {loss:.4f}  psnr {psnr:.2f} dB", enabled=enabled)

"""`BatchTrainer`: K runs of one engine trained in lockstep in one process, one kernel serving all
K (`nerfaug.nerf.batch`), each run with its own training views, seed, random numbers, optimiser
state and history, views added to any run at any step, and a run that diverges dropped without
taking the others down.

A run's random numbers are those it would draw alone (`Trainer`: its initial parameters, rays and
sample jitter come from its own generator in the same order), so a run of a batch differs from
the same run alone only by rounding, and not at all by which runs share its batch.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from nerfaug.data.views import Views
from nerfaug.device import resolve_device
from nerfaug.nerf.batch import BatchModel
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.model import NerfModel
from nerfaug.nerf.registry import DEFAULT_FIELD, build_field
from nerfaug.nerf.sampling import RunGenerators
from nerfaug.nerf.trainer import (
    PROGRESS_EVERY,
    TrainingDiverged,
    _progress_bar,
    exponential_lr,
    grown_views,
    psnr_from_mse,
    sample_training_rays,
    seeded_model,
)


class _Run:
    """One run's own state: its training views on the device, its generators and history."""

    def __init__(self, views: Views, seed: int, device: torch.device):
        self.seed, self.device = seed, device
        self.generator = torch.Generator().manual_seed(seed)
        # On a GPU, as `Trainer.step_generator`: a generator there, reseeded from (seed, step).
        self._device_generator = None if device.type == "cpu" else torch.Generator(device=device)
        self.history: list[dict] = []
        self.failure: TrainingDiverged | None = None
        self.set_views(views.materialised())

    def set_views(self, views: Views) -> None:
        self.views = views
        self.cameras = views.cameras.to(self.device)
        self.pixels = views.images.reshape(-1, 3).to(self.device)
        self.alphas = None if views.alphas is None else views.alphas.reshape(-1).to(self.device)

    def step_generator(self, step: int) -> torch.Generator:
        if self._device_generator is None:
            return self.generator
        return self._device_generator.manual_seed((self.seed * 2**32 + step) % 2**63)


@dataclass
class TrainedRun:
    """One run of a batch as the code after training sees a `Trainer`: its model (a plain
    `NerfModel`), the views it trained on, its history and device."""

    model: NerfModel
    train_views: Views
    history: list[dict]
    device: torch.device


class BatchTrainer:
    """Trains K NeRFs of one engine configuration in lockstep.

    Args:
        views: each run's initial training views (any count and image size per run).
        config: the engine; its sampler must be "proposal" (`nerfaug.nerf.batch.batch_support`).
        seeds: each run's seed: its initial parameters and random numbers are those of
            `Trainer(views[k], config, seeds[k])`.
        device, background, progress, field: as `Trainer`'s (float32 only).

    Attributes:
        model: the `BatchModel`.
        step: completed steps (every run's).
    """

    def __init__(
        self,
        views: list[Views],
        config: NerfConfig,
        seeds: list[int],
        device="cpu",
        background=(1.0, 1.0, 1.0),
        progress: bool = True,
        field: str = DEFAULT_FIELD,
    ):
        if not views or len(views) != len(seeds):
            raise ValueError(f"a trial batch needs one seed per run: {len(views)} view sets, {len(seeds)} seeds")
        self.config, self.device, self.field_name = config, resolve_device(device), field
        self.background = tuple(float(c) for c in background)
        self.progress = progress
        self.runs = [_Run(v, seed, self.device) for v, seed in zip(views, seeds)]
        models = [seeded_model(config, run.generator, self.background, field) for run in self.runs]
        self.model = BatchModel(models).to(self.device)
        self.optimizer = torch.optim.Adam(
            [
                {
                    "params": params,
                    "lr": config.optimiser.field_lr if name == "field" else config.optimiser.lr,
                    "name": name,
                }
                for name, params in self.model.param_groups().items()
            ],
            eps=config.optimiser.adam_eps,
            fused=True,
        )
        self._initial_lrs = [group["lr"] for group in self.optimizer.param_groups]
        self.step = 0

    def __len__(self) -> int:
        return len(self.runs)

    def failure(self, run: int) -> TrainingDiverged | None:
        """Why run `run` stopped training (it diverged: the step and loss), or None while it trains."""
        return self.runs[run].failure

    def add_views(self, run: int, views: Views) -> None:
        """Train run `run` on `views` too, from the next step on (as `Trainer.add_views`)."""
        current = self.runs[run]
        current.set_views(grown_views(current.views, views))

    def _batch(self, generators: list[torch.Generator]) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        """Each run's rays from its own views and generator: origins, directions (K, B, 3),
        targets (K * B, 3) and the background (None, (3,) or (K * B, 3))."""
        drawn = [
            sample_training_rays(run.cameras, run.pixels, run.alphas, self.config, self.model.background, generator)
            for run, generator in zip(self.runs, generators)
        ]
        origins = torch.stack([d[0] for d in drawn])
        directions = torch.stack([d[1] for d in drawn])
        target = torch.cat([d[2] for d in drawn])
        backgrounds = [d[3] for d in drawn]
        if backgrounds[0] is None or all(b.ndim == 1 for b in backgrounds):
            return origins, directions, target, backgrounds[0]
        rays = origins.shape[1]  # random backgrounds for some runs: one colour per ray for all
        background = torch.cat([b if b.ndim == 2 else b.expand(rays, 3) for b in backgrounds])
        return origins, directions, target, background

    def train_step(self) -> list[dict | None]:
        """Run one step of every run. Returns each run's history entry ({"step", "loss", "psnr", "losses"}),
        None for a run that has diverged (now or before: `failure` says when)."""
        self.model.train()
        generators = [run.step_generator(self.step) for run in self.runs]
        self.model.before_step(self.step)
        origins, directions, target, background = self._batch(generators)
        output = self.model(origins, directions, background, generator=RunGenerators(generators))
        losses, named = self.model.run_losses(output, target)
        values, *per_name = torch.stack([losses.detach(), *(v.detach() for v in named.values())]).tolist()
        for run, value in zip(self.runs, values):
            if run.failure is None and not math.isfinite(value):
                run.failure = TrainingDiverged(self.step, value)
        alive = [k for k, run in enumerate(self.runs) if run.failure is None]
        self.optimizer.zero_grad(set_to_none=True)
        for group, initial in zip(self.optimizer.param_groups, self._initial_lrs):
            group["lr"] = exponential_lr(
                initial, self.config.optimiser.lr_final, self.step, self.config.optimiser.lr_decay_steps
            )
        if alive:
            losses[alive].sum().backward()
            self._drop_failed_gradients()
            self.optimizer.step()
        self.step += 1
        entries: list[dict | None] = []
        for k, run in enumerate(self.runs):
            entry = None
            if run.failure is None:
                own = {name: per_name[i][k] for i, name in enumerate(named)}
                entry = {"step": self.step, "loss": values[k], "psnr": psnr_from_mse(own["rgb"]), "losses": own}
                run.history.append(entry)
            entries.append(entry)
        return entries

    def _drop_failed_gradients(self) -> None:
        """Zero the gradients of diverged runs (their NaNs stay in their own rows of every
        stacked parameter), so that Adam never writes a NaN."""
        failed = [k for k, run in enumerate(self.runs) if run.failure is not None]
        if not failed:
            return
        for param in self.model.parameters():
            if param.grad is not None:
                param.grad.view(len(self.runs), -1)[failed] = 0.0

    def train(self, until_step: int, callback: Callable[[int], None] | None = None) -> None:
        """Train every run until `self.step == until_step`; `callback(step)` every
        `PROGRESS_EVERY` steps and at the last."""
        if until_step < self.step:
            raise ValueError(f"already at step {self.step}, cannot train until step {until_step}")
        start = self.step
        with _progress_bar(self.progress) as progress:
            task = progress.add_task(
                f"training {len(self.runs)} runs", total=until_step - start, loss=float("nan"), psnr=float("nan")
            )
            while self.step < until_step:
                entries = [e for e in self.train_step() if e is not None]
                if self.step % PROGRESS_EVERY == 0 or self.step == until_step:
                    loss = sum(e["loss"] for e in entries) / max(len(entries), 1)
                    psnr = sum(e["psnr"] for e in entries) / max(len(entries), 1)
                    progress.update(task, completed=self.step - start, loss=loss, psnr=psnr)
                    if callback is not None:
                        callback(self.step)

    def run_model(self, run: int) -> NerfModel:
        """Run `run` as a plain `NerfModel` (a copy: training the batch on does not change it)."""
        with torch.random.fork_rng(devices=[]):  # its throwaway initialisation leaves the global RNG alone
            model = NerfModel(self.config, self.background, build_field(self.config, self.field_name))
        model = model.to(self.device)
        self.model.copy_run_into(run, model)
        return model

    def trained_run(self, run: int) -> TrainedRun:
        """Run `run`'s model, training views and history, for selection, evaluation and records."""
        state = self.runs[run]
        return TrainedRun(self.run_model(run), state.views, state.history, self.device)

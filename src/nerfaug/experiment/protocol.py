"""One run of the paper's protocol: train on the initial views, add the method's views at step
`add_at_step`, train on, evaluate. Everything a run writes goes into its own folder."""

from __future__ import annotations

import functools
import math
import platform
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from nerfaug.data import Views, load_dataset
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import atomic_write_json
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.store import RunKey, fingerprint, write_result
from nerfaug.hemisphere import angles_from_pose, half_hemisphere_poses

PROGRESS_EVERY = 50
# Set by a driver that shows progress in this process; called after each progress write.
on_progress = None


@dataclass
class SceneData:
    """The three sets of views a run needs."""

    initial: Views
    pool: Views
    test: Views


def scene_dataset_dir(root: Path, scene: str, config: ExperimentConfig) -> Path:
    """Where a scene's dataset lives: the user's folder, or the rendered built-in one."""
    if Path(scene).is_dir():
        return Path(scene)
    return Path(root) / "datasets" / f"{scene}-{config.resolution}px"


def prepare_scene(root: Path, scene: str, config: ExperimentConfig, progress: bool = True) -> Path:
    """Render a built-in scene once (cached), or check a user's dataset folder. Returns its folder."""
    folder = scene_dataset_dir(root, scene, config)
    if Path(scene).is_dir():
        load_dataset(folder, "train", lazy=True)  # fail early, with the dataset's own error
        if not (folder / "transforms_test.json").exists():
            raise DatasetError(folder / "transforms_test.json", "a test split is needed for evaluation: file not found")
        return folder
    from nerfaug.scenes import BUILTIN_SCENES, render_scene_dataset

    if scene not in BUILTIN_SCENES:
        raise ValueError(f"unknown scene {scene!r}: not a folder and not one of the built-in scenes {BUILTIN_SCENES}")
    return render_scene_dataset(
        scene, folder, resolution=config.resolution, pool=config.pool, test=config.n_test,
        initial=config.n_initial, samples=config.render_samples, seed=config.seed, progress=progress,
    )


def initial_view_indices(pool: Views, n: int) -> list[int]:
    """For datasets without an `initial` split: the pool views nearest (in direction) to the fixed
    half-hemisphere layout `half_hemisphere_poses(n)`, so every trial starts from the same views."""
    targets = half_hemisphere_poses(n)[:, :3, 3]
    targets = targets / targets.norm(dim=-1, keepdim=True)
    directions = pool.cameras.positions / pool.cameras.positions.norm(dim=-1, keepdim=True)
    chosen: list[int] = []
    for target in targets:
        similarity = directions @ target
        similarity[chosen] = -math.inf
        chosen.append(int(similarity.argmax()))
    return chosen


def load_scene_data(folder: Path, config: ExperimentConfig) -> SceneData:
    """Initial, pool (candidates) and test views of a dataset folder at the configured size."""
    folder = Path(folder)
    probe = load_dataset(folder, "train", lazy=True)
    downscale = max(1, probe.cameras.width // config.resolution)
    pool = load_dataset(folder, "train", downscale=downscale)
    test = load_dataset(folder, "test", downscale=downscale)
    test = test.subset(range(min(config.n_test, len(test))))
    if (folder / "transforms_initial.json").exists():
        initial = load_dataset(folder, "initial", downscale=downscale)
    else:
        chosen = initial_view_indices(pool, config.n_initial)
        initial = pool.subset(chosen)
        pool = pool.subset([i for i in range(len(pool)) if i not in set(chosen)])
    return SceneData(initial, pool, test)


def engine_config(config: ExperimentConfig, scene: str):
    from nerfaug.nerf.config import NerfConfig

    name = Path(scene).name
    overrides = {"field_lr": config.field_lr[name]} if name in config.field_lr else {}
    return NerfConfig.preset(config.engine, **overrides)


@functools.lru_cache(maxsize=1)
def cached_lpips():
    """LPIPS loaded once per process (None, with a reason in each result, when its weights are absent)."""
    from nerfaug.evaluation import load_lpips

    return load_lpips()


def train_with_progress(trainer, until_step: int, folder: Path) -> None:
    """Train to `until_step` in chunks, recording the step in `folder/progress.json` so a driver
    in any process (or on any Ray node sharing the folder) can show it."""
    while trainer.step < until_step:
        trainer.train(min(until_step, trainer.step + PROGRESS_EVERY))
        atomic_write_json(folder / "progress.json", {"step": trainer.step})
        if on_progress is not None:
            on_progress()


def run_trial(key: RunKey, dataset_dir: Path, config: ExperimentConfig, root: Path, progress: bool = False) -> dict:
    """Run one (scene, method, trial) and write its folder; result.json is written last.

    Returns the result record (also in result.json).
    """
    from nerfaug.evaluation import evaluate_views
    from nerfaug.maps import plot_hemisphere_map
    from nerfaug.nerf.trainer import Trainer
    from nerfaug.selection import select_views

    torch.set_num_threads(config.threads_per_run)
    folder = key.folder(root)
    folder.mkdir(parents=True, exist_ok=True)
    seed = config.seed + key.trial
    timing: dict[str, float] = {}

    start = time.perf_counter()
    data = load_scene_data(dataset_dir, config)
    engine = engine_config(config, key.scene)
    trainer = Trainer(data.initial, engine, seed=seed, progress=progress)
    timing["setup"] = time.perf_counter() - start

    start = time.perf_counter()
    train_with_progress(trainer, config.add_at_step, folder)
    timing["train_before"] = time.perf_counter() - start

    start = time.perf_counter()
    generator = torch.Generator().manual_seed(seed)
    selection = select_views(
        key.method, trainer.model, trainer.train_views.cameras, data.pool.cameras, config.n_new, generator
    )
    timing["selection"] = time.perf_counter() - start

    start = time.perf_counter()
    chosen = [int(i) for i in selection.indices]
    new_views = data.pool.subset(chosen)  # the pool is the oracle: its images of the chosen poses
    timing["oracle"] = time.perf_counter() - start
    trainer.add_views(new_views)

    start = time.perf_counter()
    train_with_progress(trainer, config.steps, folder)
    timing["train_after"] = time.perf_counter() - start

    start = time.perf_counter()
    evaluation = evaluate_views(
        lambda cameras, index: trainer.model.render_image(cameras, index)["rgb"],
        data.test, lpips=cached_lpips(), save_dir=folder / "renders", save_count=config.save_renders, progress=progress,
    )
    timing["evaluation"] = time.perf_counter() - start
    timing["total"] = sum(timing.values())

    azimuth, polar, _ = angles_from_pose(data.pool.cameras.camera_to_world)
    atomic_write_json(folder / "selection.json", {
        **selection.to_dict(),
        "chosen_names": [data.pool.names[i] for i in chosen],
        "chosen_poses": data.pool.cameras.camera_to_world[chosen].tolist(),
        "candidate_poses": data.pool.cameras.camera_to_world.tolist(),
        "candidate_azimuth": azimuth.tolist(), "candidate_polar": polar.tolist(),
        "train_poses": data.initial.cameras.camera_to_world.tolist(),
    })
    plot_hemisphere_map(
        data.pool.cameras.camera_to_world, selection.scores, data.initial.cameras.camera_to_world,
        data.pool.cameras.camera_to_world[chosen], path=folder / "uncertainty.png", title=f"{key.scene}: {key.method}",
    )
    atomic_write_json(folder / "metrics.json", evaluation.to_dict())
    atomic_write_json(folder / "history.json", trainer.history)
    atomic_write_json(folder / "config.json", {"experiment": asdict(config), "engine": asdict(engine)})
    result = {
        "scene": key.scene, "method": key.method, "trial": key.trial, "seed": seed,
        "fingerprint": fingerprint(config.fingerprinted()),
        "metrics": evaluation.mean, "lpips_status": evaluation.lpips_status,
        "chosen": chosen, "timing": timing, "host": platform.node(), "torch": torch.__version__,
    }
    write_result(folder, result)
    return result

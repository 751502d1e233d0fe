"""One run of the paper's protocol: train on the initial views, add the method's views at step
`add_at_step`, train on, evaluate. Everything a run writes goes into its own folder."""

from __future__ import annotations

import dataclasses
import functools
import importlib.metadata
import inspect
import json
import platform
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from nerfaug import runfiles
from nerfaug.data import Views, find_split, has_split, load_dataset, require_split
from nerfaug.data.views import spread_over_frames
from nerfaug.data.world_frame import Hemisphere
from nerfaug.device import configure_process, describe_device
from nerfaug.evaluation import evaluate_views, load_lpips
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.layout import ResultsFolder
from nerfaug.experiment.rounds import Rounds
from nerfaug.experiment.runfolder import (
    FILES,
    write_config,
    write_history,
    write_metrics,
    write_progress,
    write_selection,
    write_view_uncertainty,
)
from nerfaug.experiment.scene_views import split_captured
from nerfaug.experiment.schedule import round_steps
from nerfaug.experiment.store import (
    RunKey,
    code_version,
    fingerprint,
    run_fingerprint,
    start_run_folder,
    write_result,
)
from nerfaug.health import model_health
from nerfaug.hemisphere import angles_from_pose
from nerfaug.layouts import initial_in_half, layout_halves
from nerfaug.maps import plot_hemisphere_map
from nerfaug.nerf.trainer import Trainer, TrainingDiverged
from nerfaug.oracle import PoolOracle
from nerfaug.registry import did_you_mean
from nerfaug.scenes import BUILTIN_SCENES
from nerfaug.scenes.cache import folder_digest, load_split_cached
from nerfaug.scenes.render import dataset_manifest, render_scene_dataset, scene_spec
from nerfaug.selection import get_method, select_views
from nerfaug.selection.estimators import fisher_train_diagonal
from nerfaug.uncertainty.images import fisher_pixel_scores, view_images

PROGRESS_EVERY = 50
# Pixels across of the saved FisherRF image of a test view: three backward passes per pixel.
VIEW_FISHER_WIDTH = 24
# Set by a driver that shows progress in this process; called after each progress write.
on_progress = None


@dataclass
class SceneData:
    """The three sets of views a run needs."""

    initial: Views
    pool: Views
    test: Views
    layout: int = 0
    """Which initial layout of the configured ones the initial views are."""
    record: dict = field(default_factory=dict)
    """How the views were chosen (the test rule, the half, the frame of a captured set), for the run's record."""

    def names(self) -> dict:
        """The names of the initial and test views, as a run records them."""
        return {"initial": list(self.initial.names), "test": list(self.test.names)}


def scene_folder(scene: str) -> Path | None:
    """The user dataset folder `scene` names, or None for a built-in scene.

    A built-in name means the built-in scene; a folder of that name must be written as a path
    (`./lego`), and a bare name that is both is refused rather than guessed. Any other name must
    be an existing folder.

    Raises:
        ValueError: the name is ambiguous, or neither a built-in scene nor a folder.
    """
    explicit = "/" in scene or "\\" in scene or scene.startswith(".") or Path(scene).is_absolute()
    if scene in BUILTIN_SCENES and not explicit:
        if Path(scene).exists():
            raise ValueError(
                f"scene {scene!r} is ambiguous: a built-in scene and the folder ./{scene}; write "
                f"./{scene} (or --data ./{scene}) for the folder, or run elsewhere for the built-in scene"
            )
        return None
    if Path(scene).is_dir():
        return Path(scene)
    raise ValueError(
        f"unknown scene {scene!r}: {did_you_mean(scene, BUILTIN_SCENES)}not a dataset folder and not one of the "
        f"built-in scenes {', '.join(BUILTIN_SCENES)}"
    )


def scene_dataset_dir(root: Path, scene: str, config: ExperimentConfig) -> Path:
    """Where a scene's dataset lives: the user's folder, or the rendered built-in one."""
    folder = scene_folder(scene)
    if folder is not None:
        return folder
    return ResultsFolder(Path(root)).dataset(scene, config.resolution)


def prepare_scene(root: Path, scene: str, config: ExperimentConfig, progress: bool = True) -> Path:
    """Render a built-in scene once (cached), or check a user's dataset folder. Returns its folder."""
    folder = scene_dataset_dir(root, scene, config)
    if scene_folder(scene) is not None:
        load_dataset(folder, "train", lazy=True)  # fail early, with the dataset's own error
        if not is_captured_set(folder):  # a captured set's test views are kept apart by direction
            require_split(folder, "test", "a test split is needed for evaluation")
        return folder

    if scene not in BUILTIN_SCENES:
        raise ValueError(
            f"unknown scene {scene!r}: {did_you_mean(scene, BUILTIN_SCENES)}not a folder and not one of the "
            f"built-in scenes {', '.join(BUILTIN_SCENES)}"
        )
    return render_builtin(scene, folder, config, progress)


def render_builtin(scene: str, folder: Path, config: ExperimentConfig, progress: bool = True) -> Path:
    """Render built-in `scene` into `folder` as the protocol needs it (its resolution, pool,
    test and initial views); cached by the dataset's manifest, so a second call does nothing."""
    return render_scene_dataset(
        scene,
        folder,
        resolution=config.resolution,
        pool=config.pool,
        test=config.n_test,
        initial=config.n_initial,
        samples=config.render_samples,
        seed=config.seed,
        progress=progress,
    )


def builtin_dataset_digest(scene: str, config: ExperimentConfig) -> str:
    """A built-in scene's identity before it is rendered: a digest of the manifest its dataset is
    rendered with (`scenes.render.dataset_manifest`: the scene-building code, the bpy version and
    the render arguments), so results made on other renders are never reused."""
    val = inspect.signature(render_scene_dataset).parameters["val"].default  # what prepare_scene renders
    args = (config.resolution, config.pool, config.n_test, config.n_initial, val, config.render_samples, config.seed)
    try:
        manifest = dataset_manifest(scene_spec(scene), *args)
    except importlib.metadata.PackageNotFoundError:  # no bpy: such a scene cannot be rendered here anyway
        manifest = {"scene": scene_spec(scene), "args": args, "bpy": None}
    return fingerprint(manifest)


def dataset_cache_dir(root: Path) -> Path:
    """Where a sweep's runs share their downscaled datasets (`nerfaug.scenes.cache`)."""
    return ResultsFolder(Path(root)).dataset_cache


def is_captured_set(folder: Path) -> bool:
    """Whether `folder` is a captured set: one listing of every view (LLFF, IDR, nerfstudio), no splits."""
    return not find_split(folder, "train").format.has_splits


def load_scene_data(
    folder: Path, config: ExperimentConfig, cache_dir: Path | None = None, layout: int = 0, lazy: bool = False
) -> SceneData:
    """Initial, pool (candidates) and test views of a dataset folder at the configured size, for
    initial layout `layout` (of `config.layouts`; `nerfaug.experiment.scene_views`).

    With `cache_dir`, each split's downscaled images are read from (or written to) a cache there
    (`nerfaug.scenes.cache`), keyed by the digest of the folder's files: the same images, bit for
    bit, without decoding and shrinking every image in every run. With `lazy`, no image is read
    (the same views, cameras and names: what a run will start from, known before it runs).
    """
    folder = Path(folder)
    probe = load_dataset(folder, "train", lazy=True)
    downscale = max(1, probe.cameras.width // config.resolution)
    if lazy:
        load = functools.partial(load_dataset, folder, downscale=downscale, lazy=True)
    elif cache_dir is None:
        load = functools.partial(load_dataset, folder, downscale=downscale)
    else:
        load = functools.partial(
            load_split_cached, folder, downscale=downscale, cache_dir=cache_dir, digest=folder_digest(folder)
        )
    if is_captured_set(folder):
        return captured_scene_data(load(split="train"), config, layout)
    pool = load(split="train")
    test = load(split="test")
    test = test.subset(spread_over_frames(config.n_test, len(test)))
    if has_split(folder, "initial") and config.layouts == 1:
        return SceneData(
            load(split="initial"), pool, test, layout=0, record={"test_rule": "spread over the test split"}
        )
    azimuth = angles_from_pose(pool.cameras.camera_to_world)[0]
    half = layout_halves(azimuth, config.layouts)[layout % config.layouts]
    chosen = initial_in_half(pool.cameras.camera_to_world, config.n_initial, half, list(range(len(pool))))
    rest = [i for i in range(len(pool)) if i not in set(chosen)]
    record = {"test_rule": "spread over the test split", "half": half.to_dict()}
    return SceneData(pool.subset(chosen), pool.subset(rest), test, layout=layout % config.layouts, record=record)


def captured_scene_data(views: Views, config: ExperimentConfig, layout: int) -> SceneData:
    """A captured set (one listing, no test split) divided by `split_captured`, its cameras moved
    into the engine frame."""
    cameras = views.cameras
    split = split_captured(cameras.camera_to_world, config.n_test, config.n_initial, layout, config.layouts)
    hemisphere = Hemisphere.from_dict(split.hemisphere)
    moved = Views(hemisphere.cameras_to_engine(cameras), views.images, views.names, views.alphas, views.loader)
    record = {"test_rule": "spread over all directions", "half": split.half.to_dict(), "frame": split.hemisphere}
    return SceneData(
        moved.subset(split.initial),
        moved.subset(split.pool),
        moved.subset(split.test),
        layout=layout % config.layouts,
        record=record,
    )


@functools.lru_cache(maxsize=1)
def cached_lpips():
    """LPIPS loaded once per process (None, with a reason in each result, when its weights are absent)."""
    return load_lpips()


def train_with_progress(trainer, until_step: int, folders: list[Path]) -> None:
    """Train to `until_step` in chunks, recording the step in each run's `folder/progress.json`
    (`folders`, the runs still training) so a driver in any process (or on any Ray node sharing
    the folder) can show it."""
    while trainer.step < until_step:
        trainer.train(min(until_step, trainer.step + PROGRESS_EVERY))
        for folder in folders:
            write_progress(folder, trainer.step)
        if on_progress is not None:
            on_progress()


def save_view_uncertainty(folder: Path, trainer, test: Views, selection_config, seed: int) -> Path:
    """The first test view's render, squared error, ray entropy and FisherRF images
    (`FILES.view_uncertainty`), for the report's figure and AUSE.

    H_train is taken as the method's FisherRF would take it (`fisher_train_diagonal`), on the
    views trained on at the end, with a generator of its own; called after the evaluation, so no
    metric and no selection depends on it.
    """
    model, device = trainer.model, trainer.device
    cameras = test.cameras[[0]].to(device)
    images = view_images(model, cameras, 0)
    render = images["rgb"].clamp(0, 1).double()
    target = test.image(0).double().cpu()
    h_train = fisher_train_diagonal(
        model, trainer.train_views.cameras.to(device), selection_config, torch.Generator().manual_seed(seed)
    )
    width = min(VIEW_FISHER_WIDTH, cameras.width)
    small = cameras.resized(width, max(1, round(width * cameras.height / cameras.width)))
    fisher = fisher_pixel_scores(model, small, h_train, 0)
    return write_view_uncertainty(
        folder,
        {
            "render": render.numpy().astype("float16"),
            "error": (render - target).square().mean(-1).numpy().astype("float32"),
            "entropy": images["entropy"].numpy().astype("float32"),
            "fisher": fisher.numpy().astype("float32"),
        },
    )


@dataclass
class RunStart:
    """A run's folder, seed, views and engine, from which it trains (alone or in a batch)."""

    key: RunKey
    folder: Path
    seed: int
    data: SceneData
    engine: object  # NerfConfig


def start_run(key: RunKey, dataset_dir: Path, config: ExperimentConfig, root: Path) -> RunStart:
    """Create run `key`'s folder and load its views (the first steps of every run)."""
    folder = key.folder(root)
    start_run_folder(folder)
    data = load_scene_data(dataset_dir, config, cache_dir=dataset_cache_dir(root), layout=key.trial)
    return RunStart(key, folder, config.seed + key.trial, data, config.engine_config(key.scene))


def choose_views(
    run: RunStart,
    trained,
    config: ExperimentConfig,
    timing: dict,
    candidates: list[int] | None = None,
    generator: torch.Generator | None = None,
) -> tuple[object, list[int], Views]:
    """The method's views for `run` at a round's step, from `trained` (its run of a `Trainer`,
    `nerfaug.nerf.trainer.Run`: the views it trains on now are those the method conditions on), and the
    oracle's images of them; adds the seconds of both phases to `timing`.

    Args:
        candidates: the pool indices still to choose from (None: the whole pool).
        generator: the run's random source for its rounds (None: a new one seeded with the run's seed).

    Returns:
        the `Selection` (its indices into `candidates`), the chosen pool indices, and the new views.
    """
    start = time.perf_counter()
    generator = generator if generator is not None else torch.Generator().manual_seed(run.seed)
    candidates = candidates if candidates is not None else list(range(len(run.data.pool)))
    selection = select_views(
        run.key.method,
        trained.model,
        trained.train_views.cameras,
        run.data.pool.cameras[candidates],
        config.n_new,
        generator,
        config.selection,
    )
    timing["selection"] = timing.get("selection", 0.0) + time.perf_counter() - start
    start = time.perf_counter()
    chosen = [candidates[int(i)] for i in selection.indices]
    # The experiment's oracle is its pool: asked for the chosen poses, it answers with the pool's
    # images of them, as a robot's camera would with new ones (`nerfaug.oracle`).
    new_views = PoolOracle(run.data.pool).capture(run.data.pool.cameras.camera_to_world[chosen])
    timing["oracle"] = timing.get("oracle", 0.0) + time.perf_counter() - start
    return selection, chosen, new_views


def run_trial(key: RunKey, dataset_dir: Path, config: ExperimentConfig, root: Path, progress: bool = False) -> dict:
    """Run one (scene, method, trial) alone (a batch of one, `run_trials`) and write its folder;
    result.json is written last.

    Returns the result record (also in result.json); raises what the run failed with.
    """
    outcome = run_trials([key], {key.scene: dataset_dir}, config, root, progress)[key]
    if isinstance(outcome, BaseException):
        raise outcome
    return outcome


@dataclass
class _Trial:
    """A run of a batch as the trial loop holds it: its start, index in the trainer, timing, and
    its rounds with the one random source they draw from."""

    run: RunStart
    index: int
    timing: dict
    rounds: Rounds
    generator: torch.Generator


def run_trials(
    keys: list[RunKey], dataset_dirs: dict[str, Path], config: ExperimentConfig, root: Path, progress: bool = False
) -> dict[RunKey, dict | BaseException]:
    """Run (scene, method, trial) runs of one engine configuration as one batch, trained in
    lockstep by one `Trainer` (each run computed as it would be alone), and write each run's
    folder: train on the initial views, add the method's views at each round's step, train on,
    evaluate. A run that fails (at its start, in training, selection or evaluation) fails alone.

    Args:
        dataset_dirs: each scene's dataset folder, by the scene name in `keys`.

    Returns:
        Per key, its result record (also in its result.json, written last), or the exception it
        failed with.
    """
    # A sweep worker's entry point (in-process, pool or Ray): its process-wide torch settings.
    configure_process(threads=config.threads_per_run)
    outcomes: dict[RunKey, dict | BaseException] = {}
    runs: list[RunStart] = []
    start = time.perf_counter()
    for key in keys:
        try:
            runs.append(start_run(key, dataset_dirs[key.scene], config, root))
        except Exception as error:  # noqa: BLE001 (one run's failure is its own)
            if len(keys) == 1:
                raise
            outcomes[key] = error
    if not runs:
        return outcomes
    if len({json.dumps(asdict(run.engine), sort_keys=True) for run in runs}) != 1:
        raise ValueError("a batch trains runs of one engine configuration; group runs by engine first")
    trainer = Trainer(
        [run.data.initial for run in runs],
        runs[0].engine,
        [run.seed for run in runs],
        config.device,
        progress=progress,
        compile=config.compile,
    )
    setup = (time.perf_counter() - start) / len(runs)
    # One random source for all rounds of a run: the first round draws as a run of one round always did.
    trials = [
        _Trial(run, k, {"setup": setup}, Rounds(len(run.data.pool), len(run.data.initial)), _generator(run.seed))
        for k, run in enumerate(runs)
    ]

    def live() -> list[_Trial]:
        for trial in trials:
            failure = trainer.failure(trial.index)
            if failure is not None and trial.run.key not in outcomes:
                outcomes[trial.run.key] = failure
        return [trial for trial in trials if trial.run.key not in outcomes]

    def train_to(step: int, phase: str) -> None:
        begin = time.perf_counter()
        try:
            train_with_progress(trainer, step, [trial.run.folder for trial in live()])
        except TrainingDiverged as error:  # no run is left training
            for trial in live():
                outcomes[trial.run.key] = trainer.failure(trial.index) or error
        for trial in live():  # each run's share of the batch's time
            trial.timing[phase] = trial.timing.get(phase, 0.0) + (time.perf_counter() - begin) / len(trials)

    def each(work) -> None:
        for trial in live():
            try:
                work(trial)
            except Exception as error:  # noqa: BLE001 (one run's failure is its own)
                if len(trials) == 1:
                    raise
                outcomes[trial.run.key] = error

    def choose(trial: _Trial, step: int) -> None:
        run, rounds, trained = trial.run, trial.rounds, trainer.runs[trial.index]
        if config.rounds > 1:  # the curve's point before this round
            rounds.measure(trained.model, run.data.test, step, cached_lpips(), trial.timing)
        spent: dict[str, float] = {}
        selection, chosen, new_views = choose_views(run, trained, config, spent, rounds.remaining(), trial.generator)
        trainer.add_views(new_views, trial.index)
        rounds.add(step, selection, chosen, [run.data.pool.names[i] for i in chosen], spent)
        for phase, seconds in spent.items():
            trial.timing[phase] = trial.timing.get(phase, 0.0) + seconds

    def finish(trial: _Trial) -> None:
        rounds = trial.rounds
        # The first round's scores over the whole pool, with every view chosen in any round.
        selection = dataclasses.replace(rounds.first, indices=torch.tensor(rounds.chosen, dtype=torch.long))
        trained, size = trainer.runs[trial.index], len(trials)
        outcomes[trial.run.key] = finish_run(
            trial.run, trained, config, selection, rounds.chosen, trial.timing, progress, size, rounds
        )

    for index, step in enumerate(round_steps(config)):
        train_to(step, "train_after" if index else "train_before")
        each(lambda trial, at=step: choose(trial, at))
    train_to(config.steps, "train_after")
    each(finish)
    return outcomes


def _generator(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def finish_run(
    run: RunStart,
    trained,
    config: ExperimentConfig,
    selection,
    chosen: list[int],
    timing: dict,
    progress: bool = False,
    batch_size: int = 1,
    rounds: Rounds | None = None,
) -> dict:
    """Evaluate a trained run on its test views and write its folder, result.json last.

    Args:
        trained: the run of a `Trainer` (`nerfaug.nerf.trainer.Run`: model, train_views, history, device).
        batch_size: the runs its batch trained (kept in its record when more than one).
        rounds: the run's rounds; with more than one, the record keeps each (`Rounds.record`).

    Returns the result record (also in result.json).
    """
    key, folder, data, seed = run.key, run.folder, run.data, run.seed
    start = time.perf_counter()
    evaluation = evaluate_views(
        lambda cameras, index: trained.model.render_image(cameras, index)["rgb"],
        data.test,
        lpips=cached_lpips(),
        save_dir=runfiles.path_in(folder, FILES.renders),
        save_count=config.save_renders,
        progress=progress,
    )
    timing["evaluation"] = time.perf_counter() - start

    if config.view_uncertainty:
        start = time.perf_counter()
        save_view_uncertainty(folder, trained, data.test, config.selection, seed)
        timing["view_uncertainty"] = time.perf_counter() - start
    # Whether the NeRF learned its views at all: a run that rendered background only is kept in its
    # cell (it is what the method got) and counted on the study's page. The test views, never
    # trained on, are the untrained poses it reports on.
    health = model_health(trained.model, trained.train_views, untrained=data.test.cameras)
    timing["total"] = sum(timing.values())

    write_selection(
        folder,
        selection.to_dict(),
        [data.pool.names[i] for i in chosen],
        data.pool.cameras.camera_to_world,
        data.initial.cameras.camera_to_world,
    )
    if config.hemisphere_map:
        plot_hemisphere_map(
            data.pool.cameras.camera_to_world,
            selection.scores,
            data.initial.cameras.camera_to_world,
            data.pool.cameras.camera_to_world[chosen],
            path=runfiles.path_in(folder, FILES.uncertainty),
            title=f"{key.scene}: {key.method}",
            label=selection.score_label(config.selection),
            train_label="initial views",
        )
    write_metrics(folder, evaluation.to_dict())
    write_history(folder, trained.history)
    spec = get_method(key.method)
    write_config(
        folder,
        config.to_record(),
        asdict(run.engine),
        device=describe_device(trained.device),
        selection=selection.config.to_dict(),  # the sweep's settings, with the method's own over them
        method=spec.definition(),
    )
    result = {
        "scene": key.scene,
        "method": key.method,
        "trial": key.trial,
        "seed": seed,
        "fingerprint": run_fingerprint(fingerprint(config.fingerprinted()), spec.definition()),
        "code_version": code_version(),
        "metrics": evaluation.mean,
        "lpips_status": evaluation.lpips_status,
        "chosen": chosen,
        "layout": data.layout,
        "views": data.names() | data.record,
        "timing": timing,
        "host": platform.node(),
        "torch": torch.__version__,
        "device": describe_device(trained.device),
        "health": health.to_dict(),
    }
    if batch_size > 1:  # the batch's size changes no number: recorded, not fingerprinted
        result["batch_size"] = batch_size
    if (version := config.engine_version()) is not None:  # the reference engine's runs record none
        result["engine_version"] = version
    if rounds is not None:
        result.update(rounds.record(evaluation.mean, len(data.test), config.steps))
    write_result(folder, result)
    return result

"""The sweep driver: plan every (scene, method, trial), skip completed runs, execute the rest on
a backend (this process, a process pool, or Ray), and show progress across runs.

Resuming is the default: re-running the same command skips every run whose result.json is valid
for this configuration and redoes only missing, partial or corrupted runs.
"""

from __future__ import annotations

import concurrent.futures as futures
import os
import platform
import sys
import time
import traceback
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Literal

from rich.console import Console

from nerfaug.data import find_split, has_split, require_split
from nerfaug.device import device_kind
from nerfaug.experiment import protocol
from nerfaug.experiment.budget import Budget
from nerfaug.experiment.config import ExperimentConfig, check_workers
from nerfaug.experiment.protocol import builtin_dataset_digest, prepare_scene, run_trials, scene_folder
from nerfaug.experiment.runfolder import FILES, read_progress, write_error
from nerfaug.experiment.scene_views import split_captured
from nerfaug.experiment.schedule import check_pool
from nerfaug.experiment.store import (
    IncompatibleResults,
    RunKey,
    check_sweep,
    clear_incomplete,
    code_version,
    dataset_content_digest,
    dataset_digest,
    fingerprint,
    is_run_folder,
    read_result,
    run_fingerprint,
)
from nerfaug.experiment.workers import stop_now, worker_pool
from nerfaug.nerf.registry import check_names
from nerfaug.progress import progress_bar
from nerfaug.registry import did_you_mean
from nerfaug.selection import METHODS, get_method

Backend = Literal["local", "ray"]
# Built-in scenes stand in for the NeRF-synthetic scenes, whose images are 800 px across: the most
# `--resolution` renders them at (a larger one is a typo costing hours; `nerfaug scene render` takes any).
BUILTIN_MAX_RESOLUTION = 800
PROGRESS_FILE = FILES.progress
console = Console(stderr=True, soft_wrap=True)  # a pipe or a log gets whole lines, not 80 columns


@dataclass
class SweepOutcome:
    """What a sweep ended with: every valid result (old and new) and the runs that failed."""

    results: list[dict]
    failed: dict[str, str] = field(default_factory=dict)
    skipped: int = 0
    unstarted: int = 0
    """Runs left for a later sweep: not started within `budget_s`."""


def default_workers(config: ExperimentConfig) -> int:
    """Concurrent runs when none are asked for: one per core on a CPU (each run's threads counted);
    one at a time on a GPU (each run holds its own CUDA context)."""
    return 1 if config.device == "cuda" else max(1, (os.cpu_count() or 1) // config.threads_per_run)


def plan_runs(config: ExperimentConfig) -> list[RunKey]:
    """Every run, trial by trial: all methods of trial 0 of a scene, then of trial 1, ... so that a
    sweep stopped part-way (a study run in sittings) leaves every method with the same seeds,
    paired with each other."""
    return [
        RunKey(scene_name(scene), method, trial)
        for scene in config.scenes
        for trial in range(config.trials)
        for method in config.methods
    ]


def finished_in_plan(config: ExperimentConfig, root: Path, recorded=None) -> int:
    """How many of `config`'s runs a resume into `root` would not run again: those whose folder holds
    a result, and those `recorded` elsewhere (a study's table, keyed by `RunKey`). An estimate for the
    size line: fingerprints are checked when the sweep starts. Runs of other scenes, methods or
    trials in the same folder do not count."""
    root = Path(root)
    return sum(read_result(key.folder(root)) is not None or key in (recorded or {}) for key in plan_runs(config))


def scene_name(scene: str) -> str:
    """The name a scene has in results: a built-in name, or a dataset folder's name."""
    folder = scene_folder(scene)
    return scene if folder is None else folder.resolve().name


def _need(ok: bool, name: str, value, problem: str) -> None:
    if not ok:
        raise ValueError(f"--{name.replace('_', '-')} {value!r}: {problem}")


def check_config(config: ExperimentConfig) -> dict[str, dict]:
    """What a config's settings cannot say by themselves, checked before any work starts: each
    setting's bounds and the rules between settings were checked when `config` was made
    (`ExperimentConfig`). Here: the names looked up in registries that load torch (the methods,
    the engine's encoding and sampler), and what needs the disk (each scene a built-in name or a
    dataset folder, names apart in results, a built-in scene's size and pool, a dataset's views).

    Returns:
        Per scene (its name in results), what it runs on: {"builtin": name} or, for a user
        dataset, {"path", "digest", "width", "height", "initial", "pool", "test"}: the views and
        image size the runs use.

    Raises:
        ValueError: naming the setting, its value and what would be accepted.
        DatasetError: a user dataset is missing or malformed.
    """
    for method in config.methods:
        _need(
            method in METHODS,
            "methods",
            method,
            f"unknown selection method; {did_you_mean(method, METHODS)}see `nerfaug methods`: {', '.join(METHODS)}",
        )
    try:
        check_names(config.engine.config)
    except ValueError as error:
        raise ValueError(f"--engine {config.engine}: {error}") from None
    datasets: dict[str, dict] = {}
    for scene in config.scenes:
        name, folder = scene_name(scene), scene_folder(scene)
        _need(
            name not in datasets, "scenes", scene, f"another scene is also named {name!r} in results; rename a folder"
        )
        _need(
            folder is not None or config.resolution <= BUILTIN_MAX_RESOLUTION,
            "resolution",
            config.resolution,
            f"built-in scenes are rendered at most {BUILTIN_MAX_RESOLUTION} px across; for more, render one with "
            "`nerfaug scene render SCENE --res N --out DIR` and pass --data DIR",
        )
        if folder is None:  # a user dataset's own pool is checked with it
            check_pool(config, config.pool, "the built-in scenes' pool (--pool)")
        datasets[name] = (
            {"builtin": scene, "digest": builtin_dataset_digest(scene, config)}
            if folder is None
            else _check_user_dataset(folder, config)
        )
    return datasets


def _check_user_dataset(folder: Path, config: ExperimentConfig) -> dict:
    """What a user dataset supplies, checked against the config (see `check_config`)."""
    train_split = find_split(folder, "train")
    train = train_split.load(lazy=True)
    width, height = train.cameras.width, train.cameras.height
    _need(
        config.resolution <= width,
        "resolution",
        config.resolution,
        f"must be between 1 and the width of {folder}'s images ({width} px)",
    )
    ran = width // max(1, width // config.resolution)
    if ran != config.resolution:  # images are shrunk by an integer factor: say what would run
        sizes = sorted({width // k for k in range(1, width + 1)}, key=lambda size: abs(size - config.resolution))
        _need(
            False,
            "resolution",
            config.resolution,
            f"{folder}'s {width}-px images shrink by whole factors only; the nearest sizes are "
            f"{', '.join(str(v) for v in sorted(sizes[:3]))} (or `nerfaug scene prepare` it at any width)",
        )
    size = {"path": str(Path(folder).resolve()), "digest": dataset_digest(folder), "width": ran}
    size["height"] = height // (width // ran)
    if not train_split.format.has_splits:  # a captured set: its test views are kept apart by direction
        return size | _check_captured_set(train_split, train, config)
    test_split = require_split(folder, "test", "a test split is needed for evaluation")
    test = test_split.load(lazy=True)
    has_initial = has_split(folder, "initial") and config.layouts == 1
    if has_initial:
        initial_split = find_split(folder, "initial")
        initial = len(initial_split.load(lazy=True))
        _need(
            initial == config.n_initial,
            "n_initial",
            config.n_initial,
            f"{initial_split.listing} holds {initial} initial views; they are all used",
        )
        pool = len(train)
    else:
        _need(
            len(train) >= config.n_initial + config.n_new,
            "n_initial",
            config.n_initial,
            f"{train_split.listing} holds {len(train)} views, fewer than {config.n_initial} initial + "
            f"{config.n_new} new ones",
        )
        initial, pool = config.n_initial, len(train) - config.n_initial
    check_pool(config, pool, str(folder))
    _need(
        len(test) >= config.n_test,
        "n_test",
        config.n_test,
        f"{test_split.listing} holds only {len(test)} test views",
    )
    splits = ("train", "test", "initial") if has_initial else ("train", "test")
    return size | {
        "content": dataset_content_digest(folder, splits),
        "initial": initial,
        "pool": pool,
        "test": config.n_test,
        # How the views are chosen changes what a run measures: results of another rule are not reused.
        "views": "test spread over the test split" + ("" if has_initial else f"; {config.layouts} initial layouts"),
    }


def _check_captured_set(split, views, config: ExperimentConfig) -> dict:
    """A captured set's division into test, initial and candidate views, for every layout."""
    try:
        splits = [
            split_captured(views.cameras.camera_to_world, config.n_test, config.n_initial, k, config.layouts)
            for k in range(config.layouts)
        ]
    except ValueError as error:
        raise ValueError(f"{split.listing}: {error}") from None
    pool = min(len(s.pool) for s in splits)
    check_pool(config, pool, str(split.listing))
    return {
        "content": dataset_content_digest(split.root, ("train",)),
        "initial": config.n_initial,
        "pool": pool,
        "test": len(splits[0].test),
        "views": f"captured set: test spread over all directions; {config.layouts} initial layouts",
    }


def versions() -> dict[str, str]:
    found = {"python": platform.python_version(), "platform": platform.platform(), "code": code_version()}
    for package in ("nerfaug", "torch", "numpy", "scipy", "torchmetrics", "bpy", "ray"):
        try:
            found[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            pass
    return found


def sweep_record(config: ExperimentConfig, command: list[str] | None = None, datasets: dict | None = None) -> dict:
    """sweep.json: the fingerprint, the config, and what each scene ran on (`check_config`)."""
    fingerprinted = config.fingerprinted()
    return {
        "fingerprint": fingerprint(fingerprinted),
        "fingerprinted": fingerprinted,
        # Each method's own definition: a run's fingerprint combines the sweep's with its method's.
        "methods": {m: get_method(m).definition() for m in config.methods},
        "config": config.to_record(),
        "command": command or sys.argv,
        "versions": versions(),
        "datasets": datasets or {},
    }


def _run_unit(keys: list[RunKey], datasets: dict[str, Path], config: ExperimentConfig, root: Path) -> list[tuple]:
    """Runs as a backend executes them (top-level so process pools and Ray can pickle it): one
    batch (`run_trials`; one run is a batch of one). Returns (key, result, None) or
    (key, None, (error text, traceback)) per run: a failed run fails alone."""
    try:
        outcomes = run_trials(keys, datasets, config, root, progress=False)
    except Exception as error:  # noqa: BLE001 (the batch as a whole failed: each of its runs did)
        return [(key, None, _failure_text(error)) for key in keys]
    return [
        (key, outcome, None) if isinstance(outcome, dict) else (key, None, _failure_text(outcome))
        for key, outcome in outcomes.items()
    ]


def _failure_text(error: BaseException) -> tuple[str, str]:
    """An error's one-line text and its traceback."""
    text = "".join(traceback.format_exception_only(type(error), error)).strip()
    return text, "".join(traceback.format_exception(error))


def plan_units(todo: list[RunKey], config: ExperimentConfig, size: int) -> list[list[RunKey]]:
    """The runs to do as the backend's units of work: batches of at most `size` runs of one engine
    configuration (scenes whose field learning rate differs train apart), in plan order, so a
    sweep stopped part-way leaves whole trials; one run each when `size` is 1."""
    if size <= 1:
        return [[key] for key in todo]
    groups: dict[str, list[RunKey]] = {}
    for key in todo:
        groups.setdefault(repr(config.engine_config(key.scene)), []).append(key)
    units = [group[i : i + size] for group in groups.values() for i in range(0, len(group), size)]
    return sorted(units, key=lambda unit: todo.index(unit[0]))


def batch_size(config: ExperimentConfig, runs: int) -> int:
    """How many runs a batch holds, the one place this is decided: `config.batch` when set; auto
    (0): 1 on a CPU (where a batch gains little: BENCHMARKS.md, "Trial batches"), on a GPU as
    many as the device's free memory holds by `nerfaug.nerf.batch_size.estimated_run_bytes` (at
    most `runs` and `MAX_AUTO_BATCH`), with a line saying so. The size changes no run's numbers."""
    if config.batch >= 1:
        return config.batch
    from nerfaug.device import device_kind  # torch: only where runs are planned

    if device_kind(config.device) != "cuda" or runs <= 1:
        return 1
    from nerfaug.nerf.batch_size import auto_batch_size

    size, text = auto_batch_size(config.engine.config, config.device, runs)
    console.print(text)
    return size


def run_sweep(
    config: ExperimentConfig,
    root: Path,
    backend: Backend = "local",
    workers: int = 1,
    address: str | None = None,
    force: bool = False,
    progress: bool = True,
    command: list[str] | None = None,
    recorded: dict[RunKey, str] | None = None,
    checked: dict[str, dict] | None = None,
    budget_s: float | None = None,
) -> SweepOutcome:
    """Run every missing run of the sweep and return all results.

    Args:
        root: the results folder (created; shared storage when Ray spans machines).
        backend: "local" (this process when workers == 1, else a process pool) or "ray".
        workers: concurrent runs for the local backend.
        address: a Ray cluster to join ("auto", "ray://host:10001"); None starts a local Ray.
        force: move existing runs aside (into root/superseded/) and redo everything.
        recorded: runs finished elsewhere (a study's committed table), by key, with their run
            fingerprint: a run whose recorded fingerprint is the one it would have now is not
            run again (and is not among the results returned).

    Raises:
        ValueError, DatasetError: a setting or a dataset is wrong (checked before any work).
        IncompatibleResults, FolderRefused: `root` holds other results or files nerfaug did not write.
    """
    began = time.monotonic()
    root = Path(root)
    check_workers(workers)
    _need(budget_s is None or budget_s > 0, "budget_s", budget_s, "must be > 0 seconds")
    record = sweep_record(config, command, check_config(config) if checked is None else checked)
    keys = plan_runs(config)
    for key in [] if force else keys:  # refuse before anything is written, removed or rendered
        folder = key.folder(root)
        expected = run_fingerprint(record["fingerprint"], record["methods"][key.method])
        if folder.exists() and read_result(folder, expected) is None and not is_run_folder(folder):
            raise IncompatibleResults(
                f"{folder}: holds files nerfaug did not write; move them away or use another --out folder"
            )
    moved = check_sweep(root, record, force=force)  # with --force, moves every run aside (deletes nothing)
    if moved is not None:
        console.print(f"--force: the earlier runs and sweep.json were moved to {moved}")
    datasets = {scene_name(s): prepare_scene(root, s, config, progress=progress) for s in config.scenes}

    results, todo, elsewhere = [], [], 0
    for key in keys:
        folder = key.folder(root)
        expected = run_fingerprint(record["fingerprint"], record["methods"][key.method])
        result = read_result(folder, expected)
        if result is not None:
            results.append(result)
            continue
        if not force and (recorded or {}).get(key) == expected and not folder.exists():
            elsewhere += 1
            continue
        if clear_incomplete(folder):
            console.print(f"[yellow]redoing {key}: its folder had no valid result (interrupted or corrupted)")
        todo.append(key)
    skipped = len(results)
    if skipped or elsewhere:
        kept = f"{skipped} completed run(s) kept" + (f", {elsewhere} recorded in the table" if elsewhere else "")
        console.print(f"{kept}, {len(todo)} to run")

    units = plan_units(todo, config, batch_size(config, len(todo)) if todo else 1)
    if len(units) < len(todo):
        console.print(f"{len(todo)} run(s) in {len(units)} batch(es) of up to {max(map(len, units))}")
    deadline = None if budget_s is None else began + budget_s
    if backend == "ray":
        new_results, failed = _execute_ray(units, datasets, config, root, workers, address, progress)
        unstarted = 0
    else:
        new_results, failed, unstarted = _execute_local(units, datasets, config, root, workers, progress, deadline)
    if unstarted:
        console.print(f"{unstarted} run(s) not started within --budget-s {budget_s:g}: run the same command to go on")
    return SweepOutcome(results + new_results, failed, skipped, unstarted)


class _Display:
    """Progress across runs (done / running / failed, ETA) and each running run's iterations,
    read from the progress files the runs write. Where stderr is not a terminal: a line per
    finished run and one per quarter of a run's steps."""

    def __init__(self, total: int, root: Path, steps: int, enabled: bool):
        self.root, self.steps = root, steps
        self.progress = progress_bar(fields="{last}", console=console, enabled=enabled)
        self.overall = self.progress.add_task("runs", total=total, every=1, last="")
        self.running: dict[RunKey, int] = {}
        self.queued: list[RunKey] = []
        self.done = self.failed = 0

    def __enter__(self):
        self.progress.__enter__()
        return self

    def __exit__(self, *exc):
        self.progress.__exit__(*exc)

    def started(self, key: RunKey) -> None:
        self.running[key] = self.progress.add_task(f"  {key}", total=self.steps, every=max(1, -(-self.steps // 4)))
        self._describe()

    def queue(self, key: RunKey) -> None:
        """A run handed to another process: shown as running once it reports progress."""
        self.queued.append(key)

    def finished(self, key: RunKey, ok: bool) -> None:
        if key in self.queued:
            self.queued.remove(key)
        task = self.running.pop(key, None)
        if task is not None:
            self.progress.remove_task(task)
        self.done += ok
        self.failed += not ok
        self.progress.update(
            self.overall, advance=1, description=self._description(), last=f"({key} {'done' if ok else 'failed'})"
        )

    def poll(self) -> None:
        for key in [k for k in self.queued if (k.folder(self.root) / PROGRESS_FILE).exists()]:
            self.queued.remove(key)
            self.started(key)
        for key, task in self.running.items():
            step = read_progress(key.folder(self.root))
            if step is not None:
                self.progress.update(task, completed=step)

    def _describe(self) -> None:
        self.progress.update(self.overall, description=self._description())

    def _description(self) -> str:
        return f"runs: {self.done} done, {len(self.running)} running, {self.failed} failed"


def _execute_local(units, datasets, config, root, workers, progress, deadline=None):
    """Run `units` here (one at a time) or in a pool of `workers` processes, starting each only
    while the deadline allows. Returns (results, failed, runs not started)."""
    results, failed = [], {}
    budget = Budget(deadline)
    queue = list(units)
    total = sum(len(unit) for unit in units)
    with _Display(total, root, config.steps, progress) as display:
        if workers <= 1:
            while queue and (budget.allows() or not budget.longest):
                unit = queue.pop(0)
                for key in unit:
                    display.started(key)
                protocol.on_progress = display.poll  # the display is live here: poll it from the runs' writes
                budget.start(0)
                try:
                    outcomes = _run_unit(unit, datasets, config, root)
                finally:
                    protocol.on_progress = None
                    budget.end(0)
                _collect(outcomes, results, failed, root, display)
            return results, failed, sum(len(unit) for unit in queue)
        # Spawned workers that end with this process (`workers`). Units are handed out as workers
        # free up, so that a deadline can stop the handing out.
        with worker_pool(workers) as pool:
            try:
                _hand_out(pool, queue, workers, datasets, config, root, budget, display, results, failed)
            except BaseException:  # Ctrl-C, SIGTERM (raised as an exception by the CLI), a bug here
                stop_now(pool)
                raise
    return results, failed, sum(len(unit) for unit in queue)


def _hand_out(pool, queue: list, workers: int, datasets, config, root: Path, budget, display, results, failed) -> None:
    """Run the `queue`'s units on `pool`, handing one out as a worker frees up (so that a
    deadline can stop the handing out), filing each unit's outcomes as it ends."""
    pending = {}
    while queue or pending:
        while queue and len(pending) < workers and (budget.allows() or not budget.longest):
            unit = queue.pop(0)
            future = pool.submit(_run_unit, unit, datasets, config, root)
            pending[future] = unit
            budget.start(future)
            for key in unit:
                display.queue(key)
        if not pending:
            break
        done, _ = futures.wait(pending, timeout=0.5, return_when=futures.FIRST_COMPLETED)
        display.poll()
        for future in done:
            unit = pending.pop(future)
            budget.end(future)
            try:
                outcomes = future.result()
            except Exception as error:  # the worker itself died (e.g. killed for memory)
                outcomes = [(key, None, _failure_text(error)) for key in unit]
            _collect(outcomes, results, failed, root, display)


def _collect(outcomes: list[tuple], results: list, failed: dict, root: Path, display: _Display) -> None:
    """File a unit's outcomes: results kept, failures printed and kept in their run folders."""
    for key, result, failure in outcomes:
        if failure is None:
            results.append(result)
        else:
            failed[str(key)] = _record_failure(key, *failure, root)
        display.finished(key, failure is None)


def _record_failure(key: RunKey, text: str, trace: str, root: Path) -> str:
    """Print why a run failed and keep the reason in its folder (the report shows it)."""
    console.print(f"[red]run {key} failed: {text}")
    folder = key.folder(root)
    if folder.exists():
        write_error(folder, text, trace)
    return text


def _execute_ray(units, datasets, config, root, workers, address, progress):
    try:
        import ray
    except ImportError as error:
        raise RuntimeError("the Ray backend needs ray: pip install 'nerfaug[ray]'") from error
    started_here = not ray.is_initialized()
    if started_here:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(
                num_cpus=max(workers * config.threads_per_run, config.threads_per_run),
                include_dashboard=False,
                log_to_driver=False,
            )

    # A run asks Ray for a GPU exactly when it will compute on one.
    use_gpu = device_kind(config.device) == "cuda" and ray.cluster_resources().get("GPU", 0) > 0
    remote = ray.remote(_run_unit).options(
        num_cpus=config.threads_per_run,
        num_gpus=1 if use_gpu else 0,
        max_retries=2,
        retry_exceptions=True,
    )
    results, failed = [], {}
    try:
        with _Display(sum(len(unit) for unit in units), root, config.steps, progress) as display:
            refs = {}
            for unit in units:
                refs[remote.remote(unit, datasets, config, root)] = unit
                for key in unit:
                    display.queue(key)
            while refs:
                ready, _ = ray.wait(list(refs), num_returns=1, timeout=0.5)
                display.poll()
                for ref in ready:
                    unit = refs.pop(ref)
                    try:
                        outcomes = ray.get(ref)
                    except Exception as error:  # the task itself failed (after Ray's retries)
                        outcomes = [(key, None, _failure_text(error)) for key in unit]
                    _collect(outcomes, results, failed, root, display)
    finally:
        if started_here:
            ray.shutdown()
    return results, failed

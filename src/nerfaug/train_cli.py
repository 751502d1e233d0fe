"""CLI commands that train a capture session (`nerfaug.capture`): `train` (start a session, resume
it, or train it further, always until a given step) and `add` (add captures, then train on), with
the one training loop both run: save every few seconds, stop cleanly on Ctrl-C.

    nerfaug train DATA --out RUN --steps 1000      start a session and train it until step 1000
    nerfaug train DATA --out RUN --steps 1000      the same command again: resume from the last save
    nerfaug train RUN --steps 3000                 train an existing session until step 3000
    nerfaug add RUN --images DIR --poses poses.json --steps 1000

Nothing here imports torch at module level: `nerfaug train --help` answers at once.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import shlex
import sys
import warnings
from pathlib import Path
from time import monotonic
from typing import Annotated, Literal

import tyro

from nerfaug.cli_hints import none_means
from nerfaug.cli_options import COMMAND_LINE, given_options
from nerfaug.nerf.config import EnginePreset

RunFolder = Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
Device = Literal["auto", "cpu", "cuda"]

# `nerfaug train` and `add` save the session this often (seconds of training; a killed command
# loses at most this much), at the end, and when Ctrl-C stops them.
CHECKPOINT_EVERY_S = 60.0
_CHUNK = 10  # steps between checks for Ctrl-C and the clock
# Torch threads of a session's training: a sweep's policy (`ExperimentConfig.threads_per_run`, one
# per run unless told; tests/test_session_cli.py checks they agree), so a session and a study
# sharing a machine do not oversubscribe its cores.
THREADS = 1
# A new session's settings, as options of `nerfaug train DATA --out RUN` (written as on the
# command line): what the same command run again must repeat to resume the session.
SESSION_OPTIONS = ("engine", "seed", "split", "downscale", "centre", "radius", "up", "estimate-up")


def _device(device: str) -> str:
    """`device` resolved (auto -> cuda or cpu), or exit with one line saying why it cannot be used."""
    from nerfaug.device import resolve_device

    try:
        return str(resolve_device(device))
    except ValueError as error:
        raise SystemExit(f"--device: {error}") from None


def _open(run: Path, device: str, changing: str | None = None):
    """The session in `run`; `changing` (the command, e.g. "train") locks it first until the
    command ends, waiting for another command that changes it (`nerfaug.capture.lock`)."""
    from nerfaug.capture import CaptureSession

    if changing is not None:
        _lock(run, changing)
    with _warning_lines():
        return CaptureSession.open(run, device=_device(device), progress=True)


def _lock(run: Path, command: str) -> None:
    from nerfaug.capture.lock import hold
    from nerfaug.capture.state import SESSION_FILE

    if (run / SESSION_FILE).is_file():  # else open() says what is wrong with the folder
        hold(run, f"nerfaug {command}", on_wait=lambda line: print(line, file=sys.stderr, flush=True))


def _configure(threads: int) -> None:
    from nerfaug.device import configure_process

    if threads < 1:
        raise ValueError(f"--threads {threads}: must be >= 1 (torch threads for training)")
    configure_process(threads=threads)


@contextlib.contextmanager
def _warning_lines():
    """Show the capture's warnings (`DuplicateViews`, `UnverifiedCheckpoint`) as one line each,
    `warning: ...` on stderr."""
    from nerfaug.capture.state import DuplicateViews, UnverifiedCheckpoint

    with warnings.catch_warnings():
        warnings.simplefilter("always", DuplicateViews)
        warnings.simplefilter("always", UnverifiedCheckpoint)
        default = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, (DuplicateViews, UnverifiedCheckpoint)):
                print(f"warning: {message}", file=sys.stderr)
            else:
                default(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


@contextlib.contextmanager
def _as_options():
    """Show a library's `RequestError` as this command's option: `--n-candidates 0: must be >= 1`."""
    from nerfaug.capture.requests import RequestError

    try:
        yield
    except RequestError as error:
        raise ValueError(f"--{error.argument.replace('_', '-')} {error.value}: {error.problem}") from None


def _check_steps(steps: int) -> None:
    from nerfaug.capture.requests import check_steps

    with _as_options():
        check_steps(steps)


def _check_period(seconds: float) -> None:
    if not seconds > 0:
        raise ValueError(f"--checkpoint-every {seconds}: must be > 0 (seconds between saves)")


def resume_command(run: Path, target: int) -> str:
    """The shell command that trains the session in `run` on until step `target`."""
    return f"nerfaug train {shlex.quote(str(run))} --steps {target}"


def _train(session, target: int, every_s: float = CHECKPOINT_EVERY_S) -> dict:
    """Train until step `target`, saving once `every_s` seconds passed since the last save, and at
    the end. A first Ctrl-C stops at the next step boundary and saves; a second stops at once,
    keeping the last save.

    Raises:
        Interrupted: after Ctrl-C, saying at which step the session was saved and the command that
            goes on from there.
    """
    import signal

    from nerfaug.errors import Interrupted
    from nerfaug.progress import progress_bar

    asked = []

    def stop(signum, frame):
        if asked:
            raise KeyboardInterrupt
        asked.append(signum)
        print("stopping after the current steps to save the session (Ctrl-C again: stop at once)", file=sys.stderr)

    show, session.trainer.progress = session.trainer.progress, False  # one bar over the chunks
    start, saved, last = session.step, session.step, {"step": session.step}
    saved_at = monotonic()
    previous = signal.signal(signal.SIGINT, stop)
    bar = progress_bar(fields="psnr {psnr:.2f} dB", enabled=show)
    go_on = resume_command(session.run_dir, target)
    try:
        with bar:
            task = bar.add_task("training", total=max(target - start, 0), psnr=float("nan"))
            while session.step < target and not asked:
                last = session.train(min(_CHUNK, target - session.step))
                bar.update(task, completed=session.step - start, psnr=last.get("psnr", float("nan")))
                if monotonic() - saved_at >= every_s:
                    session.save()
                    saved, saved_at = session.step, monotonic()
        session.save()
    except KeyboardInterrupt:
        raise Interrupted(
            f"{session.run_dir}: interrupted at step {session.step}; the session saved at step {saved} "
            f"is kept (`{go_on}` goes on from there)"
        ) from None
    finally:
        signal.signal(signal.SIGINT, previous)
        session.trainer.progress = show
    if asked:
        raise Interrupted(
            f"{session.run_dir}: interrupted; the session is saved at step {session.step} "
            f"(`{go_on}` goes on from there)"
        )
    return last


def _create(data: Path, out: Path, split: str | None, **options):
    """A new session on `data` in `out`, after one line saying how many views it trains on and why."""
    from nerfaug.capture import CaptureSession
    from nerfaug.capture.dataset import default_split
    from nerfaug.data import load_dataset

    why = f"split '{split}' of {data}"
    if split is None:
        split, why = default_split(data)
    print(f"training on {len(load_dataset(data, split, lazy=True))} views: {why}", flush=True)
    with _warning_lines(), _as_options():
        session = CaptureSession.create(data, out, split=split, progress=True, **options)
    _lock(out, "train")
    h = session.hemisphere
    print(
        f"session created in {out}: {len(session.trainer.train_views)} views; hemisphere centre "
        f"{[round(c, 4) for c in h.centre]}, radius {h.radius:.4g}, up {[round(u, 4) for u in h.up]}"
    )
    return session


def _close(a, b) -> bool:
    """Two vectors (or numbers) equal to within float noise."""
    a, b = (tuple(x) if isinstance(x, (tuple, list)) else (x,) for x in (a, b))
    return len(a) == len(b) and all(math.isclose(float(x), float(y), rel_tol=1e-6, abs_tol=1e-9) for x, y in zip(a, b))


def _unit(v) -> tuple[float, ...]:
    norm = math.sqrt(sum(float(x) ** 2 for x in v)) or 1.0
    return tuple(float(x) / norm for x in v)


def _setting_differences(state, asked: dict, data: Path | None) -> list[str]:
    """The settings `asked` (option name -> value, `SESSION_OPTIONS`; a missing name is not
    compared) that differ from the session's `state`, as "--OPTION VALUE (the session's: VALUE)";
    `data`, when given, is compared with the dataset the session started from."""
    h, estimated = state.hemisphere, state.hemisphere_estimated

    def words(value) -> str:
        return " ".join(f"{x:g}" for x in value) if isinstance(value, tuple) else str(value)

    def fixed(name: str, value, ours):
        """Compare an option that is None (estimate it) or a value with the session's."""
        if value is None:
            return None if estimated.get(name, False) else f"not given, so estimated (the session's: {words(ours)})"
        if estimated.get(name, False) or not _close(value, ours):
            theirs = "estimated" if estimated.get(name, False) else words(ours)
            return f"{words(value)} (the session's: {theirs})"
        return None

    found = []
    if data is not None and Path(data).resolve() != Path(state.source.data_dir).resolve():
        found.append(f"DATA {data} (the session's: {state.source.data_dir})")
    checks = {
        "engine": lambda v: None if v == state.preset else f"{v} (the session's: {state.preset})",
        "seed": lambda v: None if int(v) == state.seed else f"{v} (the session's: {state.seed})",
        "split": lambda v: None if v == state.source.split else f"{v} (the session's: {state.source.split})",
        "downscale": lambda v: None if int(v) == state.downscale else f"{v} (the session's: {state.downscale})",
        "centre": lambda v: fixed("centre", None if v is None else tuple(v), h.centre),
        "radius": lambda v: fixed("radius", v, h.radius),
        "estimate-up": lambda v: (
            None
            if bool(v) == bool(estimated.get("up", False))
            else f"{'on' if v else 'off'} (the session's: {'on' if estimated.get('up') else 'off'})"
        ),
        "up": lambda v: _up_difference(tuple(v), asked, h.up, bool(estimated.get("up", False)), words),
    }
    for name in SESSION_OPTIONS:
        if name in asked:
            problem = checks[name](asked[name])
            if problem is not None:
                found.append(f"--{name} {problem}")
    return found


def _up_difference(up: tuple, asked: dict, ours: tuple, estimated: bool, words) -> str | None:
    """How --up differs from the session's pole, or None: an estimated pole is compared through
    --estimate-up when that is asked too (one difference, not two)."""
    if asked.get("estimate-up") or (estimated and "estimate-up" in asked):
        return None
    if not estimated and _close(_unit(up), ours):
        return None
    return f"{words(up)} (the session's: {'estimated' if estimated else words(ours)})"


def train(
    path: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="DATA|RUN")],
    out: Annotated[
        Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(required when DATA|RUN is a dataset)")
    ] = None,
    steps: int = 1000,
    engine: EnginePreset = "cpu",
    seed: int = 0,
    split: Annotated[
        str | None, none_means('"initial" for a dataset `nerfaug scene render` wrote, else "train"', "STR")
    ] = None,
    downscale: int = 1,
    centre: Annotated[tuple[float, float, float] | None, none_means("the point the cameras look at", "X Y Z")] = None,
    radius: Annotated[float | None, none_means("the cameras' mean distance to the centre", "FLOAT")] = None,
    up: tuple[float, float, float] = (0.0, 0.0, 1.0),
    estimate_up: bool = False,
    device: Device = "auto",
    checkpoint_every: float = CHECKPOINT_EVERY_S,
    threads: int = THREADS,
) -> None:
    """Train a capture session until step --steps: start it on a dataset, resume it, or train it further.

    `nerfaug train DATA --out RUN --steps N` copies the dataset's views into RUN/dataset, builds the
    NeRF and trains it until step N, saving every --checkpoint-every seconds. Run the same command
    again (after Ctrl-C, a crash or a kill) and it resumes from the last save, saying from which
    step; once the session is at step N it only says so. `nerfaug train RUN --steps N` trains an
    existing session until step N: give a larger N to train further.

    Args:
        path: a Blender (transforms_{split}.json) or nerfstudio (transforms.json) dataset folder,
            or an existing run folder.
        out: the run folder to create (or, holding a session made by the same command, to resume).
        steps: train until the session's step count reaches this.
        engine: the NeRF engine preset (the names `nerfaug run --engine` takes): cpu (small, for a
            CPU), nerfacto-cpu and nerfacto-cpu-last-sample (nerfacto's design shrunk for a CPU),
            paper (the paper's, for a GPU), test (tiny, for tests).
        seed: seeds the model, its training and every proposal.
        split: the Blender split holding the captured views (a dataset `nerfaug scene render`
            wrote keeps its candidate pool in "train").
        downscale: train on images shrunk by this integer factor.
        centre: the hemisphere's centre, world space.
        radius: the hemisphere's radius.
        up: the hemisphere's pole direction, world space (the world is z-up by default).
        estimate_up: take the pole from the cameras' mean up axis instead of --up.
        device: where the NeRF trains: auto (cuda when this machine has a GPU, else cpu), cpu, cuda.
        checkpoint_every: save the session after this many seconds of training (and at the end).
        threads: torch threads for training (one by default, as each run of a sweep).
    """
    from nerfaug.capture.state import SESSION_FILE, SessionState

    _check_steps(steps)
    _check_period(checkpoint_every)
    values = {
        "engine": engine,
        "seed": seed,
        "split": split,
        "downscale": downscale,
        "centre": centre,
        "radius": radius,
        "up": tuple(up),
        "estimate-up": estimate_up,
    }
    if (path / SESSION_FILE).exists():  # `nerfaug train RUN`: only the options given are compared
        run, data = path, None
        state = SessionState.read(run)
        if out is not None:
            raise SystemExit(
                f"{path} is a session folder (at step {state.step}); drop --out: `{resume_command(run, steps)}`"
            )
        argv = COMMAND_LINE.get()
        # On the command line an option given at its default is given all the same; from Python
        # (no command line), the options that differ from the defaults are.
        if argv is not None:
            given = given_options(list(values), argv)
        else:
            defaults = {name: p.default for name, p in inspect.signature(train).parameters.items()}
            given = {k for k, v in values.items() if v != defaults[k.replace("-", "_")]}
        asked = {k: v for k, v in values.items() if k in given}
    elif out is not None and (out / SESSION_FILE).exists():  # the same command again: every setting counts
        from nerfaug.capture.dataset import default_split

        run, data = out, path
        state = SessionState.read(run)
        asked = {**values, "split": split if split is not None else default_split(path)[0]}
    else:
        if out is None:
            raise SystemExit(f"{path} is a dataset: give the run folder to create with --out RUN")
        _configure(threads)
        session = _create(
            path,
            out,
            preset=engine,
            seed=seed,
            split=split,
            centre=centre,
            radius=radius,
            up="estimate" if estimate_up else up,
            downscale=downscale,
            device=_device(device),
        )
        _finish(session, steps, checkpoint_every)
        return
    differences = _setting_differences(state, asked, data)
    if differences:
        raise ValueError(
            f"{run} holds a session (at step {state.step}) made with other settings: {'; '.join(differences)}. "
            f"`{resume_command(run, steps)}` trains it on with its own settings; to start a session with "
            "these, give a new --out"
        )
    if state.step >= steps:
        from nerfaug.capture import CaptureSession, integrity
        from nerfaug.capture.state import CHECKPOINT_FILE, SessionError

        # The captures and the checkpoint are checked all the same: a damaged session is never
        # reported as done.
        session = CaptureSession.open(run, load_model=False)
        if not (run / CHECKPOINT_FILE).is_file():
            raise SessionError(f"{run / CHECKPOINT_FILE}: checkpoint not found; the run folder is incomplete")
        integrity.check_checkpoint(run / CHECKPOINT_FILE, session.state.integrity)
        print(
            f"{run}: already at step {state.step} (--steps {steps}); nothing to do. Give a larger --steps to "
            "train further"
        )
        return
    _configure(threads)
    session = _open(run, device, changing="train")
    verb = "resuming" if data is not None else "training"
    print(
        f"{run}: {verb} from step {session.step}, its last save, until step {steps} "
        f"({len(session.trainer.train_views)} views)",
        flush=True,
    )
    _finish(session, steps, checkpoint_every)


def _finish(session, target: int, every_s: float) -> None:
    last = _train(session, target, every_s)
    psnr = f", training PSNR {last['psnr']:.2f} dB" if "psnr" in last else ""
    print(f"{session.run_dir}: step {session.step}{psnr}")


def add(
    run: RunFolder,
    images: Path,
    poses: Path,
    steps: int = 1000,
    device: Device = "auto",
    checkpoint_every: float = CHECKPOINT_EVERY_S,
    threads: int = THREADS,
) -> None:
    """Add captured images at the poses of a poses JSON, then train on for --steps more steps.

    Each frame of the JSON is matched to the image in --images whose file name (without
    extension) is the frame's file_path stem. Everything is checked before anything is written:
    on an error the dataset is left as it was. Unlike `nerfaug train`, whose --steps is the step
    to reach, --steps here counts from the session's step when the images are added (the command
    prints the step it trains until); an interrupted `add` keeps the added images, and
    `nerfaug train RUN --steps TARGET`, as it prints, finishes the training.

    Args:
        run: the session's run folder.
        images: folder holding the captured images (PNG, JPEG, ...).
        poses: the poses JSON (as `nerfaug propose` writes it, or your robot's actual poses in
            the same format).
        steps: training steps to run after adding, counted from the session's step (0: add only).
        device: where the NeRF trains: auto (cuda when available, else cpu), cpu, cuda.
        checkpoint_every: save the session after this many seconds of training (and at the end).
        threads: torch threads for training (one by default, as each run of a sweep).
    """
    _check_steps(steps)  # before anything is written: a refused call changes nothing
    _check_period(checkpoint_every)
    _configure(threads)
    session = _open(run, device, changing="add")
    with _warning_lines():
        names = session.add_views(images, poses)
    session.save()  # the addition's record is kept even if training is stopped at once
    print(
        f"added {len(names)} views ({', '.join(names)}); the dataset now has {len(session.trainer.train_views)} views"
    )
    if steps:
        print(f"training from step {session.step} until step {session.step + steps}", flush=True)
    last = _train(session, session.step + steps, checkpoint_every)
    if steps:
        print(f"step {session.step}, training PSNR {last['psnr']:.2f} dB")

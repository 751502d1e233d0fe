"""CLI commands that train a capture session (`nerfaug.capture`): `train` (start a session, resume
it, or train it further, always until a given step) and `add` (add captures, then train on); both
run the session's one training loop (`CaptureSession.train_for`: a save every --checkpoint-every
seconds), here stopped cleanly by Ctrl-C.

    nerfaug train DATA --out RUN --steps 1000      start a session and train it until step 1000
    nerfaug train DATA --out RUN --steps 1000      the same command again: resume from the last save
    nerfaug train RUN --steps 3000                 train an existing session until step 3000
    nerfaug add RUN --images DIR --poses poses.json --steps 1000

`nerfaug train --help` answers at once: nothing here imports torch at module level, so the
capture core's sessions (`nerfaug.capture.session`, `state`, `lock`, `dataset`) and the device
set-up are imported inside the functions that use them; the settings' schema
(`nerfaug.capture.requests`) is light.
"""

from __future__ import annotations

import contextlib
import dataclasses
import shlex
import signal
import sys
import warnings
from pathlib import Path
from typing import Annotated, Literal

import tyro

from nerfaug.capture.requests import (
    CHECKPOINT_EVERY_S,
    RequestError,
    SessionSettings,
    Split,
    check_steps,
    given_form,
    replaced_by,
    words,
)
from nerfaug.capture.runfolder import SESSION_FILE
from nerfaug.errors import Interrupted

RunFolder = Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
Device = Literal["auto", "cpu", "cuda"]
# The session settings the command line gives, each None unless given (at its default value
# too): `nerfaug train RUN` compares those alone with the session's.
GivenSettings = given_form(SessionSettings)
Settings = Annotated[GivenSettings, tyro.conf.arg(name="")]
# Torch threads of a session's training: a sweep's policy (`ExperimentConfig.threads_per_run`, one
# per run unless told; tests/test_session_cli.py checks they agree), so a session and a study
# sharing a machine do not oversubscribe its cores.
THREADS = 1
# A field of a schema named otherwise on the command line.
OPTION_NAMES = {"preset": "engine"}


def option(field: str) -> str:
    """A schema's field as the option that sets it: "estimate_up" -> "--estimate-up"."""
    return "--" + OPTION_NAMES.get(field, field).replace("_", "-")


@contextlib.contextmanager
def as_options(omitted: tuple[str, ...] = ()):
    """Show a `RequestError` as this command's option and value: `--n-candidates 0: must be >= 1`
    (fields under `omitted`, e.g. "constraints.", are options without that prefix)."""
    try:
        yield
    except RequestError as error:
        name = error.argument
        for prefix in omitted:
            name = name.removeprefix(prefix)
        value = "" if dataclasses.is_dataclass(error.value) else f" {words(error.value)}"  # a group of options
        raise ValueError(f"{option(name.partition('[')[0])}{value}: {error.problem}") from None


def checked(request):
    """`request.checked()`, a refused value shown as its option."""
    with as_options(omitted=("constraints.",)):
        return request.checked()


def _device(device: str) -> str:
    """`device` resolved (auto -> cuda or cpu), or exit with one line saying why it cannot be used."""
    from nerfaug.device import resolve_device  # torch (see the module docstring)

    try:
        return str(resolve_device(device))
    except ValueError as error:
        raise SystemExit(f"--device: {error}") from None


def _configure(threads: int) -> None:
    from nerfaug.device import configure_process  # torch (see the module docstring)

    if threads < 1:
        raise ValueError(f"--threads {threads}: must be >= 1 (torch threads)")
    configure_process(threads=threads)


def _open(run: Path, device: str, changing: str | None = None):
    """The session in `run`; `changing` (the command, e.g. "train") locks it first until the
    command ends, waiting for another command that changes it (`nerfaug.capture.lock`)."""
    from nerfaug.capture.session import CaptureSession  # torch (see the module docstring)

    if changing is not None:
        _lock(run, changing)
    with warning_lines():
        return CaptureSession.open(run, device=_device(device), progress=True)


def _lock(run: Path, command: str) -> None:
    from nerfaug.capture.lock import hold  # torch (see the module docstring)

    if (run / SESSION_FILE).is_file():  # else opening it says what is wrong with the folder
        hold(run, f"nerfaug {command}", on_wait=lambda line: print(line, file=sys.stderr, flush=True))


@contextlib.contextmanager
def warning_lines():
    """Show the capture's warnings (`DuplicateViews`, `UnverifiedCheckpoint`) as one line each,
    `warning: ...` on stderr."""
    from nerfaug.capture.state import DuplicateViews, UnverifiedCheckpoint  # torch (see the module docstring)

    kinds = (DuplicateViews, UnverifiedCheckpoint)
    with warnings.catch_warnings():
        for kind in kinds:
            warnings.simplefilter("always", kind)
        default = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, kinds):
                print(f"warning: {message}", file=sys.stderr)
            else:
                default(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


def _check_training(steps: int, checkpoint_every: float) -> None:
    """--steps and --checkpoint-every, checked before anything is read or written."""
    with as_options():
        check_steps(steps)
    if not checkpoint_every > 0:
        raise ValueError(f"--checkpoint-every {checkpoint_every}: must be > 0 (seconds between saves)")


def resume_command(run: Path, target: int) -> str:
    """The shell command that trains the session in `run` on until step `target`."""
    return f"nerfaug train {shlex.quote(str(run))} --steps {target}"


def train_session(session, steps: int, checkpoint_every: float) -> dict:
    """`session.train_for(steps, checkpoint_every)`, where a first Ctrl-C stops at the next chunk
    and saves, a second at once, keeping the last save.

    Raises:
        Interrupted: after Ctrl-C, saying at which step the session was saved and the command that
            goes on from there.
    """
    asked = []

    def stop(signum, frame):
        if asked:
            raise KeyboardInterrupt
        asked.append(signum)
        print("stopping after the current steps to save the session (Ctrl-C again: stop at once)", file=sys.stderr)

    go_on = resume_command(session.run_dir, session.step + steps)
    previous = signal.signal(signal.SIGINT, stop)
    try:
        last = session.train_for(steps, checkpoint_every, stop=lambda: bool(asked))
    except KeyboardInterrupt:
        raise Interrupted(
            f"{session.run_dir}: interrupted at step {session.step}; the session saved at step "
            f"{session.saved_step} is kept (`{go_on}` goes on from there)"
        ) from None
    finally:
        signal.signal(signal.SIGINT, previous)
    if asked:
        raise Interrupted(
            f"{session.run_dir}: interrupted; the session is saved at step {session.step} "
            f"(`{go_on}` goes on from there)"
        )
    return last


def train(
    path: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="DATA|RUN")],
    out: Annotated[Path | None, replaced_by("required when DATA|RUN is a dataset", "PATH")] = None,
    steps: int = 1000,
    settings: Settings = GivenSettings(),  # noqa: B008 -- read-only: nothing given
    split: Annotated[
        Split | None, replaced_by('"initial" for a dataset `nerfaug scene render` wrote, else "train"', "STR")
    ] = None,
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
        split: the Blender split holding the captured views (a dataset `nerfaug scene render`
            wrote keeps its candidate pool in "train").
        device: where the NeRF trains: auto (cuda when this machine has a GPU, else cpu), cpu, cuda.
        checkpoint_every: save the session after this many seconds of training (and at the end).
        threads: torch threads for training (one by default, as each run of a sweep).
    """
    _check_training(steps, checkpoint_every)
    run, data, given = _which_session(path, out, _given(settings, split), steps)
    settings = _settings(settings)
    if run is None:
        _configure(threads)
        _finish(_create(path, out, settings, split, device), steps, checkpoint_every)
    elif not _at_step(run, data, settings, split, given, steps):
        _configure(threads)
        _train_further(_open(run, device, changing="train"), steps, checkpoint_every, resuming=data is not None)


def _which_session(path: Path, out: Path | None, given: set[str], steps: int):
    """(run folder, its dataset, the settings to compare) for `nerfaug train PATH [--out OUT]`:
    `train RUN` compares the settings `given`, the same `train DATA --out RUN` again every setting
    (None); (None, PATH, None) when a new session is to be made."""
    if (path / SESSION_FILE).exists():
        if out is not None:
            raise SystemExit(f"{path} is a session folder; drop --out: `{resume_command(path, steps)}`")
        return path, None, given
    if out is not None and (out / SESSION_FILE).exists():
        return out, path, None
    if out is None:
        raise SystemExit(f"{path} is a dataset: give the run folder to create with --out RUN")
    return None, path, None


def _given(settings, split: str | None) -> set[str]:
    """The names of the settings given (not None), even at their default values, "split" among them."""
    given = {name for name, value in dataclasses.asdict(settings).items() if value is not None}
    return given if split is None else given | {"split"}


def _settings(settings) -> SessionSettings:
    """The session settings `settings` (a `GivenSettings`) gives, those not given at their defaults."""
    return SessionSettings(**{name: value for name, value in dataclasses.asdict(settings).items() if value is not None})


def _at_step(run: Path, data: Path | None, settings: SessionSettings, split, given, steps: int) -> bool:
    """Whether the session in `run` is at step `steps` already (and says so), once the settings
    `given` (every one when None) agree with the session's."""
    from nerfaug.capture.dataset import default_split  # torch (see the module docstring)
    from nerfaug.capture.folder import SessionFolder

    folder = SessionFolder.open(run)  # the captures are checked all the same: a damaged session is never done
    if given is None:
        given = {f.name for f in dataclasses.fields(SessionSettings)} | {"split"}
        split = default_split(data)[0] if split is None else split
    _refuse_other_settings(folder, data, checked(settings), split, given, steps)
    if folder.state.step < steps:
        return False
    folder.checkpoint()
    step = folder.state.step
    print(_reached(run, step, steps))
    return True


def _reached(run: Path, step: int, steps: int) -> str:
    return f"{run}: already at step {step} (--steps {steps}); nothing to do. Give a larger --steps to train further"


def _refuse_other_settings(folder, data: Path | None, settings: SessionSettings, split, given, steps: int) -> None:
    """Refuse, in one line, settings `given` that differ from the session's in `folder` (and a
    dataset `data` other than the one it started from)."""
    state = folder.state
    found = [
        f"{option(name)} {asked} (the session's: {theirs})"
        for name, asked, theirs in settings.differences(state.settings(), given)
    ]
    if "split" in given and split is not None and split != state.source.split:
        found.append(f"--split {split} (the session's: {state.source.split})")
    if data is not None and Path(data).resolve() != Path(state.source.data_dir).resolve():
        found.insert(0, f"DATA {data} (the session's: {state.source.data_dir})")
    if found:
        raise ValueError(
            f"{folder.run_dir} holds a session (at step {state.step}) made with other settings: {'; '.join(found)}. "
            f"`{resume_command(folder.run_dir, steps)}` trains it on with its own settings; to start a session "
            "with these, give a new --out"
        )


def _train_further(session, target: int, every_s: float, resuming: bool) -> None:
    if session.step >= target:  # another command reached it while this one waited for the lock
        print(_reached(session.run_dir, session.step, target), flush=True)
        return
    verb = "resuming" if resuming else "training"
    print(
        f"{session.run_dir}: {verb} from step {session.step}, its last save, until step {target} "
        f"({session.summary().views} views)",
        flush=True,
    )
    _finish(session, target - session.step, every_s)


def _create(data: Path, out: Path, settings: SessionSettings, split: str | None, device: str):
    """A new session on `data` in `out`, after one line saying how many views it trains on and why."""
    from nerfaug.capture.dataset import default_split  # torch (see the module docstring)
    from nerfaug.capture.session import CaptureSession
    from nerfaug.data import load_dataset

    why = f"split '{split}' of {data}"
    if split is None:
        split, why = default_split(data)
    print(f"training on {len(load_dataset(data, split, lazy=True))} views: {why}", flush=True)
    with warning_lines(), as_options():
        session = CaptureSession.create(data, out, settings, split=split, device=_device(device), progress=True)
    _lock(out, "train")
    h = session.hemisphere
    print(
        f"session created in {out}: {session.summary().views} views; hemisphere centre "
        f"{[round(c, 4) for c in h.centre]}, radius {h.radius:.4g}, up {[round(u, 4) for u in h.up]}"
    )
    return session


def _finish(session, steps: int, every_s: float) -> None:
    last = train_session(session, steps, every_s)
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
    _check_training(steps, checkpoint_every)  # before anything is written: a refused call changes nothing
    _configure(threads)
    session = _open(run, device, changing="add")
    with warning_lines():
        names = session.add_views(images, poses)
    session.save()  # the addition's record is kept even if training is stopped at once
    print(f"added {len(names)} views ({', '.join(names)}); the dataset now has {session.summary().views} views")
    if steps:
        print(f"training from step {session.step} until step {session.step + steps}", flush=True)
    last = train_session(session, steps, checkpoint_every)
    if steps:
        print(f"step {session.step}, training PSNR {last['psnr']:.2f} dB")

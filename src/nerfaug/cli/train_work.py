"""The work of `nerfaug train` and `nerfaug add`, whose options are in `nerfaug.cli.train`: a new,
resumed or further trained session, captures added, and the session's one training loop
(`CaptureSession.train_for`: a save every --checkpoint-every seconds), here stopped cleanly by
Ctrl-C. This module loads torch: `nerfaug.cli.train` imports it only when a command runs.
"""

from __future__ import annotations

import contextlib
import shlex
import signal
import sys
import warnings
from pathlib import Path

from nerfaug import runfiles
from nerfaug.capture.dataset import HELD_OUT_KEY, default_split
from nerfaug.capture.folder import SessionFolder
from nerfaug.capture.lock import hold
from nerfaug.capture.requests import SessionSettings, check_threads
from nerfaug.capture.runfolder import SESSION_FILE, remove_unfinished
from nerfaug.capture.session import CaptureSession
from nerfaug.capture.state import DuplicateViews, TiltedPole, UnverifiedCheckpoint, pole_settings
from nerfaug.cli.option_names import as_options, option
from nerfaug.data import find_split, load_dataset
from nerfaug.data.formats import has_split
from nerfaug.data.world_frame import TooFewCameras
from nerfaug.device import configure_process, resolve_device
from nerfaug.errors import Interrupted
from nerfaug.health import EmptyModelWarning
from nerfaug.nerf.engine import Engine
from nerfaug.nerf.trainer import TrainingDiverged
from nerfaug.selection.selectors import DirectDraw, UniformFill
from nerfaug.training_log import Logger, LoggerUnavailable, open_log


def train(
    path: Path,
    out: Path | None,
    steps: int,
    settings: SessionSettings,
    given: set[str],
    split,
    device: str,
    checkpoint_every: float,
    threads: int,
    start,
    logger: Logger = "none",
):
    """`nerfaug train PATH` (`nerfaug.cli.train.train`) with its options: `settings` the session
    settings (checked), `given` the names of those the command line gave, `start` a sparse start
    (or None)."""
    configure(threads)
    run, data, compared = _which_session(path, out, given, steps)
    if run is None:
        existed = out.exists()
        session = _create(path, out, settings, split, device, start)
        try:
            _finish(session, steps, checkpoint_every, logger)
        except TrainingDiverged as error:  # nothing of a session that cannot train is kept
            remove_unfinished(out, existed)
            raise ValueError(f"{diverged(error, session.state.engine)}; {out} was not kept") from None
    elif not _at_step(run, data, settings, split, compared, steps):
        session = open_session(run, device, changing="train")
        try:
            _train_further(session, steps, checkpoint_every, resuming=data is not None, logger=logger)
        except TrainingDiverged as error:  # the last save, made before the loss was lost, is kept
            kept = f"the session saved at step {session.saved_step} is kept"
            raise ValueError(f"{run}: {diverged(error, session.state.engine)}; {kept}") from None


def diverged(error: TrainingDiverged, engine) -> str:
    """A divergence as the fault of the engine's settings (`engine`: a session's record of it),
    naming them as options: "training diverged at step 1 (loss nan) with --engine test
    --engine.optimiser.field-lr 1e30: ..."."""
    named = Engine.read(engine)
    fix = "change them" if named.settings else "choose another engine or --seed"
    return (
        f"training diverged at step {error.step} (loss {error.loss}) with {named.options()}: "
        f"these settings do not train on this data ({fix}, e.g. a smaller learning rate)"
    )


def add(
    run: Path,
    images: Path,
    poses: Path,
    steps: int,
    device: str,
    checkpoint_every: float,
    threads: int,
    logger: Logger = "none",
):
    """`nerfaug add RUN` (`nerfaug.cli.train.add`) with its options."""
    configure(threads)
    session = open_session(run, device, changing="add")
    with warning_lines():
        names = session.add_views(images, poses)
    session.save()  # the addition's record is kept even if training is stopped at once
    print(f"added {len(names)} views ({', '.join(names)}); the dataset now has {session.summary().views} views")
    if steps:
        print(f"training from step {session.step} until step {session.step + steps}", flush=True)
    last = train_session(session, steps, checkpoint_every, logger)
    if steps:
        print(f"step {session.step}, training PSNR {last['psnr']:.2f} dB")
        health = session.health()
        if health.empty:
            print(f"warning: {health.line()}", flush=True)


def device_name(device: str) -> str:
    """`device` resolved (auto -> cuda or cpu), or exit with one line saying why it cannot be used."""
    try:
        return str(resolve_device(device))
    except ValueError as error:
        raise SystemExit(f"--device: {error}") from None


def configure(threads: int) -> None:
    """torch set up for this command (`configure_process`) on --threads threads."""
    with as_options():
        configure_process(threads=check_threads(threads))


def open_session(run: Path, device: str, changing: str | None = None):
    """The session in `run`; `changing` (the command, e.g. "train") locks it first until the
    command ends, waiting for another command that changes it (`nerfaug.capture.lock`)."""
    if changing is not None:
        _lock(run, changing)
    with warning_lines():
        return CaptureSession.open(run, device=device_name(device), progress=True)


def _lock(run: Path, command: str) -> None:
    if runfiles.exists(run, SESSION_FILE):  # else opening it says what is wrong with the folder
        hold(run, f"nerfaug {command}", on_wait=lambda line: print(line, file=sys.stderr, flush=True))


@contextlib.contextmanager
def warning_lines():
    """Show the capture's warnings (`DuplicateViews`, `TiltedPole`, `UnverifiedCheckpoint`,
    `EmptyModelWarning`, and a sampler's `UniformFill` and `DirectDraw`) as one line each,
    `warning: ...` on stderr."""
    kinds = (DuplicateViews, TiltedPole, UnverifiedCheckpoint, EmptyModelWarning, UniformFill, DirectDraw)
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


def resume_command(run: Path, target: int) -> str:
    """The shell command that trains the session in `run` on until step `target`."""
    return f"nerfaug train {shlex.quote(str(run))} --steps {target}"


def train_session(session, steps: int, checkpoint_every: float, logger: Logger = "none") -> dict:
    """`session.train_for(steps, checkpoint_every)`, where a first Ctrl-C stops at the next chunk
    and saves, a second at once, keeping the last save; `logger` logs the training as it goes
    (`nerfaug.training_log`: "tensorboard" into RUN/tensorboard).

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
    try:
        log = open_log(logger, session.run_dir)
    except LoggerUnavailable as error:
        raise SystemExit(str(error)) from None
    previous = signal.signal(signal.SIGINT, stop)
    try:
        last = session.train_for(steps, checkpoint_every, stop=lambda: bool(asked), log=log)
    except KeyboardInterrupt as stop:
        raise Interrupted(
            f"{session.run_dir}: {Interrupted.why(stop)} at step {session.step}; the session saved at "
            f"step {session.saved_step} is kept (`{go_on}` goes on from there)",
            stop,
        ) from None
    finally:
        signal.signal(signal.SIGINT, previous)
        if log is not None:
            log.close()
    if asked:
        raise Interrupted(
            f"{session.run_dir}: interrupted; the session is saved at step {session.step} "
            f"(`{go_on}` goes on from there)"
        )
    return last


def _which_session(path: Path, out: Path | None, given: set[str], steps: int):
    """(run folder, its dataset, the settings to compare) for `nerfaug train PATH [--out OUT]`:
    `train RUN` compares the settings `given`, the same `train DATA --out RUN` again every setting
    (None); (None, PATH, None) when a new session is to be made."""
    if runfiles.exists(path, SESSION_FILE):
        if out is not None:
            raise SystemExit(f"{path} is a session folder; drop --out: `{resume_command(path, steps)}`")
        return path, None, given
    if out is not None and runfiles.exists(out, SESSION_FILE):
        return out, path, None
    if out is None:
        raise SystemExit(f"{path} is a dataset: give the run folder to create with --out RUN")
    return None, path, None


def _at_step(run: Path, data: Path | None, settings: SessionSettings, split, given, steps: int) -> bool:
    """Whether the session in `run` is at step `steps` already (and says so), once the settings
    `given` (every one when None) agree with the session's."""
    folder = SessionFolder.open(run)  # the captures are checked all the same: a damaged session is never done
    _refuse_other_settings(folder, data, settings, split, given, steps)
    if folder.state.step < steps:
        return False
    folder.checkpoint()
    step = folder.state.step
    print(_reached(run, step, steps))
    return True


def _reached(run: Path, step: int, steps: int) -> str:
    return f"{run}: already at step {step} (--steps {steps}); nothing to do. Give a larger --steps to train further"


def _refuse_other_settings(folder, data: Path | None, settings: SessionSettings, split, given, steps: int) -> None:
    """Refuse, in one line, what asks for another session than the one in `folder`
    (`SessionState.differences`)."""
    if data is not None:  # the same `train DATA --out RUN` again: the default pole decided as on creation
        settings = pole_settings(settings, find_split(data, split or default_split(data)[0]))
    found = folder.state.differences(settings, given, split, data)
    if found:
        named = "; ".join(
            f"{'DATA' if name == 'data' else option(name)} {asked} (the session's: {theirs})"
            for name, asked, theirs in found
        )
        raise ValueError(
            f"{folder.run_dir} holds a session (at step {folder.state.step}) made with other settings: {named}. "
            f"`{resume_command(folder.run_dir, steps)}` trains it on with its own settings; to start a session "
            "with these, give a new --out"
        )


def _train_further(session, target: int, every_s: float, resuming: bool, logger: Logger = "none") -> None:
    if session.step >= target:  # another command reached it while this one waited for the lock
        print(_reached(session.run_dir, session.step, target), flush=True)
        return
    verb = "resuming" if resuming else "training"
    print(
        f"{session.run_dir}: {verb} from step {session.step}, its last save, until step {target} "
        f"({session.summary().views} views)",
        flush=True,
    )
    _finish(session, target - session.step, every_s, logger)


def _engine(settings: SessionSettings) -> str:
    """The engine a new session trains with, said at its start (`nerfaug run`'s default is another)."""
    return f"engine {settings.engine} (--engine chooses another)"


def _create(data: Path, out: Path, settings: SessionSettings, split: str | None, device: str, start=None):
    """A new session on `data` in `out`, after one line saying how many views it trains on and why."""

    if split is None and start is not None:
        split = "train"  # a sparse start chooses among all the views (a rendered scene's pool included)
    why = f"split '{split}' of {data}"
    if split is None:
        split, why = default_split(data)
    if start is None:
        count = len(load_dataset(data, split, lazy=True))
        print(f"training on {count} view{'s' * (count != 1)}: {why}; {_engine(settings)}", flush=True)
        if not has_split(data, "test"):
            print(
                f"no view is held out: {data} has no test split and the session trains on all of it "
                "(--initial N keeps a spread quarter apart for `nerfaug eval`)",
                flush=True,
            )
    try:
        with warning_lines(), as_options():
            session = CaptureSession.create(
                data, out, settings, split=split, device=device_name(device), progress=True, start=start
            )
    except TooFewCameras as error:
        listing = find_split(data, split).listing
        raise ValueError(
            f"{listing}: {error.count} view{'s' * (error.count != 1)}, and estimating the hemisphere's centre needs "
            "at least 2: capture at least 2 views, or give --centre X Y Z and --radius R"
        ) from None
    if start is not None:  # said once the start is found possible (a refused one says only why)
        count, kept = session.state.start["of"], session.state.start.get(HELD_OUT_KEY)
        apart = "" if kept is None else _kept_apart(len(kept), count)
        print(
            f"training on {start.initial} of the {count} views of {why} (layout {start.layout}: one half of the "
            f"object); {apart}the other {count - start.initial - len(kept or [])} are the candidates "
            f"`nerfaug propose` chooses from; {_engine(settings)}",
            flush=True,
        )
    _lock(out, "train")
    pole = session.state.hemisphere_estimated.get("up", False)
    said = " (up: the cameras' mean up axis; --up X Y Z gives another)" if pole else ""
    print(f"session created in {out}: {session.summary().views} views; hemisphere {session.hemisphere}{said}")
    return session


def _kept_apart(kept: int, count: int) -> str:
    """The sparse start's line on the views a set without a test split kept apart for testing."""
    if not kept:
        return f"no view is held out for testing ({count} views are too few to keep a quarter apart); "
    return f"{kept} views spread over all directions are held out for testing (`nerfaug eval` scores them); "


def _finish(session, steps: int, every_s: float, logger: Logger = "none") -> None:
    last = train_session(session, steps, every_s, logger)
    psnr = f", training PSNR {last['psnr']:.2f} dB" if "psnr" in last else ""
    print(f"{session.run_dir}: step {session.step}{psnr}")
    health = session.health()
    if health.empty:  # said now, not first when a proposal is refused
        print(f"warning: {health.line()}", flush=True)

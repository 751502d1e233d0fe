"""CLI commands that train a capture session (`nerfaug.capture`): `train` (start a session, resume
it, or train it further, always until a given step) and `add` (add captures, then train on), their
options and help; their work, which loads torch, is `nerfaug.cli.train_work`, imported when one
runs, so that `nerfaug train --help` answers at once.

    nerfaug train DATA --out RUN --steps 1000      start a session and train it until step 1000
    nerfaug train DATA --out RUN --steps 1000      the same command again: resume from the last save
    nerfaug train RUN --steps 3000                 train an existing session until step 3000
    nerfaug add RUN --images DIR --poses poses.json --steps 1000
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import tyro

from nerfaug import runfiles
from nerfaug.capture.requests import (
    CHECKPOINT_EVERY_S,
    SessionSettings,
    SparseStart,
    Split,
    check_checkpoint_every,
    check_steps,
    given_form,
    replaced_by,
)
from nerfaug.capture.runfolder import SESSION_FILE
from nerfaug.cli.option_names import as_options, checked, engine_with
from nerfaug.device_choice import Device
from nerfaug.nerf.engine import Engine
from nerfaug.training_log import Logger, LoggerUnavailable, require

RunFolder = Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
# The session settings the command line gives, each None unless given (at its default value
# too): `nerfaug train RUN` compares those alone with the session's.
GivenSettings = given_form(SessionSettings)
Settings = Annotated[GivenSettings, tyro.conf.arg(name="")]
# Torch threads of a session's training: a sweep's policy (`ExperimentConfig.threads_per_run`, one
# per run unless told; tests/cli/test_session_commands.py checks they agree), so a session and a study
# sharing a machine do not oversubscribe its cores.
THREADS = 1


def _check_training(steps: int, checkpoint_every: float, logger: Logger) -> None:
    """--steps, --checkpoint-every and --logger, checked before anything is read or written."""
    with as_options():
        check_steps(steps)
        check_checkpoint_every(checkpoint_every)
    try:
        require(logger)
    except LoggerUnavailable as error:
        raise SystemExit(str(error)) from None


def with_engine_settings(settings: GivenSettings, given: dict | None, path: Path | None = None) -> GivenSettings:
    """`settings` whose engine is --engine (or else the engine of the session in `path`, or the
    default) with the --engine.GROUP.SETTING `given` (nested: {"field": {"hidden_dim": 32}})
    changed: one `Engine`, read and checked here, which the session records."""
    if not given:
        return settings  # the engine is checked with the other settings (`checked`)
    base = settings.engine or (_recorded_engine(path) if path is not None else None) or SessionSettings().engine
    # Before the session is opened: an unknown setting, or a value out of its bounds, is one line naming it.
    return replace(settings, engine=engine_with(base, given))


def _recorded_engine(run: Path) -> Engine | None:
    """The engine a session in `run` records (format 2: "engine"; 1: "preset"), or None where there
    is none to read (opening the session then says what is wrong)."""
    try:
        data = json.loads(runfiles.read_text(run, SESSION_FILE))
        return Engine.read(data.get("engine" if data.get("format") == 2 else "preset"))
    except (OSError, ValueError, AttributeError):
        return None


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
    initial: Annotated[int | None, replaced_by("every view of the split", "INT")] = None,
    layout: Annotated[int | None, replaced_by("0, with --initial", "INT")] = None,
    logger: Logger = "none",
    engine_settings: tyro.conf.Suppress[dict | None] = None,
) -> None:
    """Train a capture session until step --steps: start it on a dataset, resume it, or train it further.

    `nerfaug train DATA --out RUN --steps N` copies the dataset's views into RUN/dataset, builds the
    NeRF and trains it until step N, saving every --checkpoint-every seconds. Run the same command
    again (after Ctrl-C, a crash or a kill) and it resumes from the last save, saying from which
    step; once the session is at step N it only says so. `nerfaug train RUN --steps N` trains an
    existing session until step N: give a larger N to train further.

    Any setting of the engine is an option too, over the engine's own value:
    --engine.GROUP.SETTING VALUE (e.g. --engine.field.hidden-dim 32); `nerfaug engines` lists them.

    Args:
        path: a dataset folder (Blender: transforms_{split}.json; nerfstudio: transforms.json, lens
            distortion undone; LLFF: poses_bounds.npy; IDR/DTU: cameras_sphere.npz), or an
            existing run folder.
        out: the run folder to create (or, holding a session made by the same command, to resume).
        steps: train until the session's step count reaches this.
        split: the Blender split holding the captured views (a dataset `nerfaug scene render`
            wrote keeps its candidate pool in "train").
        device: where the NeRF trains.
        checkpoint_every: save the session after this many seconds of training (and at the end).
        threads: torch threads for training (one by default, as each run of a sweep).
        initial: a sparse start: train on this many of the split's views, on one half of the
            object (as the paper's experiments start); the others become the candidates
            `nerfaug propose RUN` chooses from, named as in DATA, so that `nerfaug add RUN
            --images DATA/<their folder> --poses poses.json` adds the chosen ones.
        layout: with --initial, the half the views lie on: 0, 1 or 2, each turned a third of
            the way round.
        logger: "tensorboard": also write each loss as TensorBoard scalars into RUN/tensorboard
            while training (`tensorboard --logdir RUN/tensorboard`; needs `pip install
            'nerfaug[tensorboard]'`).
        engine_settings: the --engine.GROUP.SETTING given (nested by component; read apart from
            these options, `nerfaug.cli.engine_options`), changed over the engine's own.
    """
    _check_training(steps, checkpoint_every, logger)
    settings = with_engine_settings(settings, engine_settings, path)
    checked_settings = checked(settings.filled())  # the one check of each session setting, before anything is read
    start = None
    if initial is None and layout is not None:  # a layout places a sparse start's views: alone it means nothing
        raise ValueError(f"--layout {layout}: places the views of a sparse start; give --initial N with it")
    if initial is not None:
        with as_options():
            start = SparseStart(initial=initial, layout=layout or 0).checked()
    from nerfaug.cli import train_work  # torch: here, so that `nerfaug train --help` loads none

    train_work.train(
        path,
        out,
        steps,
        checked_settings,
        settings.given_names(),
        split,
        device,
        checkpoint_every,
        threads,
        start,
        logger,
    )


def add(
    run: RunFolder,
    images: Path,
    poses: Path,
    steps: int = 1000,
    device: Device = "auto",
    checkpoint_every: float = CHECKPOINT_EVERY_S,
    threads: int = THREADS,
    logger: Logger = "none",
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
        device: where the NeRF trains.
        checkpoint_every: save the session after this many seconds of training (and at the end).
        threads: torch threads for training (one by default, as each run of a sweep).
        logger: "tensorboard": also write each loss as TensorBoard scalars into RUN/tensorboard.
    """
    _check_training(steps, checkpoint_every, logger)  # before anything is written: a refused call changes nothing
    from nerfaug.cli import train_work  # torch: here, so that `nerfaug add --help` loads none

    train_work.add(run, images, poses, steps, device, checkpoint_every, threads, logger)

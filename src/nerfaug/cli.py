"""The `nerfaug` command: scenes, experiments, reports, and the active-capture loop.

nerfaug scene render lego --out data/lego      render a built-in scene as a Blender dataset
nerfaug scene prepare DOWNLOAD --out data/mic  ready a downloaded dataset (NeRF-synthetic, LLFF, DTU)
nerfaug run --preset quick --out results/quick  the paper's experiment, then its report
nerfaug report results/quick                    (re)write report.md and report.html
nerfaug study --out results/study               which method wins where, on which engine
nerfaug methods                                 list the view-selection methods
nerfaug train DATA --out RUN --steps N          active capture: train on what you have (until step N),
nerfaug propose RUN --n 6 --out poses.json      ask where to look next,
nerfaug add RUN --images DIR --poses poses.json add what you captured, and go on training
nerfaug render-proposals RUN --poses poses.json --scene lego --out DIR
                                                (simulation) render the proposed views with Blender
nerfaug uncertainty RUN --poses poses.json --out DIR
                                                what the NeRF sees and how unsure it is, per pixel
nerfaug export RUN --format nerfstudio --out DIR
nerfaug eval RUN --data DATA --split test       PSNR/SSIM/LPIPS of the session on held-out views
nerfaug serve --root SESSIONS                   the same over HTTP, for a robot (API docs at /docs)
"""

from __future__ import annotations

import inspect
import os
import re
import sys
import warnings
from pathlib import Path
from typing import Annotated

import tyro

from nerfaug.cli_options import COMMAND_LINE

Positional = tyro.conf.Positional
# Each command's home, "module:function": a command's module is imported only when it runs, so
# `nerfaug train --help` answers without loading torch (what the experiment commands' options need).
COMMANDS = {
    "scene": "nerfaug.cli:scene",
    "run": "nerfaug.run_cli:run",
    "report": "nerfaug.cli:report",
    "methods": "nerfaug.cli:methods",
    "study": "nerfaug.study_cli:study",
    "train": "nerfaug.train_cli:train",
    "propose": "nerfaug.session_cli:propose",
    "add": "nerfaug.train_cli:add",
    "export": "nerfaug.session_cli:export",
    "eval": "nerfaug.session_cli:evaluate",
    "render-proposals": "nerfaug.session_cli:render_proposals",
    "uncertainty": "nerfaug.serve_cli:uncertainty",
    "serve": "nerfaug.serve_cli:serve",
}


def reflow(docstring: str | None) -> str | None:
    """`docstring` with each paragraph, and each argument's description under "Args:", on one
    line: the help wraps text to the terminal's width, and keeps the line breaks it is given."""
    if not docstring:
        return docstring
    lines: list[str] = []
    for line in inspect.cleandoc(docstring).splitlines():
        indent, text = len(line) - len(line.lstrip()), line.strip()
        previous = lines[-1] if lines else ""
        joins = (
            text
            and previous.strip()
            and not re.fullmatch(r"[A-Z][A-Za-z ]*:", previous.strip())  # a section's heading
            and not text.startswith(("- ", "* "))
            and (indent == 0 or indent > len(previous) - len(previous.lstrip()))
        )
        if joins:
            lines[-1] = f"{previous} {text}"
        else:
            lines.append(line.rstrip())
    return "\n".join(lines)


def scene_render(
    scene: Annotated[str, Positional, tyro.conf.arg(metavar="SCENE")],
    out: Path,
    res: int = 200,
    pool: int = 300,
    test: int = 200,
    initial: int = 6,
    samples: int = 16,
    seed: int = 0,
) -> None:
    """Render a built-in scene (lego, chair, materials, cow) or a .blend file as a Blender-format dataset.

    Writes transforms_train.json (the candidate pool, uniform on the hemisphere),
    transforms_initial.json (fixed views on one half), transforms_test.json and transforms_val.json.
    Cached: the same arguments render nothing the second time.

    Args:
        scene: a built-in scene name or a path to a .blend file.
        out: the dataset folder to write.
        res: image width and height in pixels.
        pool: candidate views, uniform over the hemisphere.
        test: test views, spread over the hemisphere.
        initial: initial training views, all on one half of the hemisphere.
        samples: Cycles samples per pixel.
        seed: seeds the pool's poses and Cycles' noise.
    """
    from nerfaug.scenes import render_scene_dataset

    path = render_scene_dataset(
        scene, out, resolution=res, pool=pool, test=test, initial=initial, samples=samples, seed=seed, progress=True
    )
    print(f"dataset written to {path}")


def scene_prepare(
    source: Annotated[Path, Positional, tyro.conf.arg(metavar="SOURCE")],
    out: Path,
    width: int = 100,
) -> None:
    """Prepare a downloaded dataset for `nerfaug run` and `nerfaug study`: a copy with images
    WIDTH px across and masks merged into their alpha.

    SOURCE may be a NeRF-synthetic folder (transforms_{train,val,test}.json), an LLFF capture
    (poses_bounds.npy, images/, optional masks/), a DTU scan in the IDR/NeuS layout
    (cameras_sphere.npz, image/ or images/, mask/) or a nerfstudio folder. A capture without a
    test split is written as one transforms.json; the experiments keep test views apart from it,
    spread over all directions. prepared.json records the source's digest. Running it again with
    the same source and width does nothing.

    Args:
        source: the downloaded dataset folder (it is only read).
        out: the folder to write (new or empty).
        width: image width in pixels (any size up to the source's; area-averaged).
    """
    from nerfaug.data.prepare import prepare_dataset

    path = prepare_dataset(source, out, width)
    print(f"dataset prepared in {path}")


def paper_tables():
    """The rows of the paper's ablation tables as the method registry defines them, and its
    protocol's image side (the experiments' paper preset): what a report compares with the paper,
    as `nerfaug.report.PaperTables`."""
    from nerfaug.experiment.config import PROTOCOL_PRESETS
    from nerfaug.report import PaperTables
    from nerfaug.selection import TABLE_I_ROWS, TABLE_II_ROWS

    return PaperTables(TABLE_I_ROWS, TABLE_II_ROWS, PROTOCOL_PRESETS["paper"].resolution)


def report(results: Positional[Path]) -> None:
    """Write report.md and a self-contained report.html for a results folder.

    Args:
        results: the folder `nerfaug run --out` wrote.
    """
    from nerfaug.report import ReportError, write_report

    try:
        paths = write_report(results, paper_tables())
    except ReportError as error:
        raise SystemExit(str(error)) from None
    for path in paths:
        print(path)


def methods() -> None:
    """List the view-selection methods and what each does."""
    from nerfaug.selection import METHODS

    width = max(len(name) for name in METHODS)
    for name, spec in METHODS.items():
        settings = ", ".join(f"{k}={v}" for k, v in spec.settings.items())
        print(f"{name:<{width}}  {spec.description}" + (f" [settings: {settings}]" if settings else ""))


def exit_code(error: BaseException) -> int:
    """2 for bad input (a value, file or folder the user gave), 1 for a failure of the work."""
    from nerfaug.errors import NerfaugError

    if isinstance(error, NerfaugError):
        return error.exit_code
    bad_path = (FileNotFoundError, NotADirectoryError, IsADirectoryError, FileExistsError, PermissionError)
    return 2 if isinstance(error, (ValueError, *bad_path)) else 1


def one_line(error: BaseException) -> str:
    """The error as one line: its message (the project's errors name file, field and value)."""
    from nerfaug.errors import NerfaugError

    text = " ".join(str(error).split())
    expected = (NerfaugError, ValueError, OSError)
    if not isinstance(error, expected):
        text = f"internal error ({type(error).__name__}: {text}); run again with --debug for the traceback"
    return text or type(error).__name__


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, as Ctrl-C is: `finally` blocks run, so a child process
    (the Blender render worker) is stopped and what was saved is kept."""


def _terminate(signum, frame):
    raise Terminated


def wants_help(argv: list[str]) -> bool:
    """Whether `argv` asks for help (nothing is run then, so nothing is set up for running)."""
    return not argv or "-h" in argv or "--help" in argv


def main(argv: list[str] | None = None) -> None:
    """The `nerfaug` command. Errors end as one line on stderr (exit 2: bad input, 1: failure,
    130: Ctrl-C, 143: SIGTERM); `--debug` or NERFAUG_DEBUG=1 shows the traceback instead."""
    import signal
    import threading

    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv or os.environ.get("NERFAUG_DEBUG", "") not in ("", "0")
    argv = [arg for arg in argv if arg != "--debug"]
    # Flushing denormals (configure_process) makes numpy warn, once per float type, that the
    # smallest subnormal is zero: expected, and eight lines of noise before any one-line error.
    warnings.filterwarnings("ignore", message="The value of the smallest subnormal", category=UserWarning)
    previous = None
    if threading.current_thread() is threading.main_thread():  # signal handlers live in the main thread
        previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        if wants_help(argv):  # --help imports no torch: it only reads the options
            _dispatch(argv)
        else:
            from nerfaug.capture.lock import command_scope
            from nerfaug.device import configure_process

            configure_process()
            with command_scope():  # a session a command locked is unlocked when it ends
                _dispatch(argv)
    except SystemExit as done:
        if isinstance(done.code, str):  # a command's own refusal: one line, bad input
            print(f"nerfaug: {' '.join(done.code.split())}", file=sys.stderr)
            raise SystemExit(2) from None
        raise
    except KeyboardInterrupt as stop:
        if debug:
            raise
        why = "stopped (SIGTERM)" if isinstance(stop, Terminated) else "interrupted"
        print(f"nerfaug: {why}; files already written are kept (finished runs, saved sessions)", file=sys.stderr)
        raise SystemExit(143 if isinstance(stop, Terminated) else 130) from None
    except Exception as error:
        if debug:
            raise
        print(f"nerfaug: {one_line(error)}", file=sys.stderr)
        raise SystemExit(exit_code(error)) from None
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def scene() -> None:
    """Scenes: `nerfaug scene render SCENE --out DIR` renders a built-in scene (lego, chair,
    materials, cow) or a .blend file as a Blender-format dataset; `nerfaug scene prepare SOURCE
    --out DIR` readies a downloaded dataset (NeRF-synthetic, LLFF, DTU) for experiments (`--help`
    of each)."""
    _dispatch(["scene", "--help"])


# Options that were renamed so that each name means one thing across commands: (command, old) -> new.
RENAMED = {("train", "--preset"): "--engine"}


def _check_renamed(argv: list[str]) -> None:
    """Name the new spelling of a renamed option, instead of tyro's "unrecognized option"."""
    for word in argv[1:]:
        new = RENAMED.get((argv[0], word.partition("=")[0]))
        if new is not None:
            raise SystemExit(
                f"{word.partition('=')[0]}: `nerfaug {argv[0]}` takes the NeRF engine preset as {new} "
                "(--preset is an experiment's protocol, in `nerfaug run` and `nerfaug study`)"
            )


def command(name: str):
    """The function of the command `name` (`COMMANDS`), its module imported now, its docstring
    reflowed for the help."""
    import importlib

    module, _, function = COMMANDS[name].partition(":")
    found = getattr(importlib.import_module(module), function)
    found.__doc__ = reflow(found.__doc__)
    return found


def _dispatch(argv: list[str]) -> None:
    if argv[:1] == ["scene"]:
        scene_commands = {"render": scene_render, "prepare": scene_prepare}
        for function in scene_commands.values():
            function.__doc__ = reflow(function.__doc__)
        tyro.extras.subcommand_cli_from_dict(scene_commands, args=argv[1:], prog="nerfaug scene")
        return
    parsing = COMMAND_LINE.set(tuple(argv))
    try:
        if argv and argv[0] in COMMANDS:  # only this command's module is imported
            _check_renamed(argv)
            tyro.cli(command(argv[0]), args=argv[1:], prog=f"nerfaug {argv[0]}")
            return
        if not argv or argv[0] in ("-h", "--help"):
            print(__doc__.strip())
            print()
        tyro.extras.subcommand_cli_from_dict(
            {name: command(name) for name in COMMANDS},
            args=argv,
            prog="nerfaug",
            description="Choose which views to add when a NeRF has too little data.",
        )
    finally:
        COMMAND_LINE.reset(parsing)


if __name__ == "__main__":
    main()

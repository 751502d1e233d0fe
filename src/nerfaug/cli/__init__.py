"""The `nerfaug` command: scenes, experiments, reports, and the active-capture loop.

nerfaug scene render lego --out data/lego      render a built-in scene as a Blender dataset
nerfaug scene prepare DOWNLOAD --out data/mic  ready a downloaded dataset (NeRF-synthetic, LLFF, DTU)
nerfaug run --preset quick --out results/quick  the paper's experiment, then its report
nerfaug report results/quick                    (re)write report.md and report.html
nerfaug study --out results/study               which method wins where, on which engine
nerfaug methods                                 list the view-selection methods
nerfaug engines                                 list the NeRF engines and their settings
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
nerfaug view RUN                                a session in the browser: cameras, scores, live render
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import os
import re
import signal
import sys
import threading
import warnings
from dataclasses import dataclass

import tyro

from nerfaug.cli.engine_options import ENGINE_COMMANDS, engine_settings_given, split_engine_options
from nerfaug.errors import Interrupted, NerfaugError, Terminated
from nerfaug.registry import unknown
from nerfaug.schema import built_then_checked

# Each command's home, "module:function": a command's module is imported only when it runs, so
# `nerfaug train --help` answers without loading torch (what the experiment commands' options need).
# A command is a function, or a dataclass whose instance is called; one with a `from_preset` class
# method starts from the preset `--preset` names (`parse`).
COMMANDS = {
    "scene": "nerfaug.cli.scene:scene",
    "run": "nerfaug.cli.run:Run",
    "report": "nerfaug.cli.run:report",
    "methods": "nerfaug.cli.run:methods",
    "engines": "nerfaug.cli.engine_options:engines",
    "study": "nerfaug.cli.study:Study",
    "train": "nerfaug.cli.train:train",
    "propose": "nerfaug.cli.session:propose",
    "add": "nerfaug.cli.train:add",
    "export": "nerfaug.cli.session:export",
    "eval": "nerfaug.cli.session:evaluate",
    "render-proposals": "nerfaug.cli.session:render_proposals",
    "uncertainty": "nerfaug.cli.uncertainty:uncertainty",
    "serve": "nerfaug.cli.serve:serve",
    "view": "nerfaug.cli.view:view",
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


def exit_code(error: BaseException) -> int:
    """2 for bad input (a value, file or folder the user gave), 1 for a failure of the work."""
    if isinstance(error, NerfaugError):
        return error.exit_code
    bad_path = (FileNotFoundError, NotADirectoryError, IsADirectoryError, FileExistsError, PermissionError)
    return 2 if isinstance(error, (ValueError, *bad_path)) else 1


def one_line(error: BaseException) -> str:
    """The error as one line: its message (the project's errors name file, field and value)."""
    text = " ".join(str(error).split())
    expected = (NerfaugError, ValueError, OSError)
    if not isinstance(error, expected):
        text = f"internal error ({type(error).__name__}: {text}); run again with --debug for the traceback"
    return text or type(error).__name__


def _terminate(signum, frame):
    raise Terminated


def wants_help(argv: list[str]) -> bool:
    """Whether `argv` asks for help (nothing is run then, so nothing is set up for running)."""
    return not argv or "-h" in argv or "--help" in argv


def main(argv: list[str] | None = None) -> None:
    """The `nerfaug` command. Errors end as one line on stderr (exit 2: bad input, 1: failure,
    130: Ctrl-C, 143: SIGTERM); `--debug` or NERFAUG_DEBUG=1 shows the traceback instead."""
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
        _run(argv)
    except SystemExit as done:
        if isinstance(done.code, str):  # a command's own refusal: one line, bad input
            print(f"nerfaug: {' '.join(done.code.split())}", file=sys.stderr)
            raise SystemExit(2) from None
        raise
    except KeyboardInterrupt as stop:
        if debug:
            raise
        stopped = Interrupted(
            f"{Interrupted.why(stop)}; files already written are kept (finished runs, saved sessions)", stop
        )
        print(f"nerfaug: {stopped}", file=sys.stderr)
        raise SystemExit(stopped.exit_code) from None
    except Exception as error:
        if debug:
            raise
        print(f"nerfaug: {one_line(error)}", file=sys.stderr)
        raise SystemExit(exit_code(error)) from None
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _run(argv: list[str]) -> None:
    """The command `argv`, set up for running unless it asks for help."""
    if wants_help(argv):  # --help imports no torch: it only reads the options
        _dispatch(argv)
        return
    # Imported here: both load torch, which `--help` (above) answers without.
    from nerfaug.capture.lock import command_scope
    from nerfaug.device import configure_process

    configure_process()
    with command_scope():  # a session a command locked is unlocked when it ends
        _dispatch(argv)


# Options that were renamed so that each name means one thing across commands: (command, old) -> new.
RENAMED = {("train", "--preset"): "--engine"}


def _check_renamed(argv: list[str]) -> None:
    """Name the new spelling of a renamed option, instead of tyro's "unrecognized option"."""
    for word in argv[1:]:
        new = RENAMED.get((argv[0], word.partition("=")[0]))
        if new is not None:
            raise SystemExit(
                f"{word.partition('=')[0]}: `nerfaug {argv[0]}` takes the NeRF engine as {new} "
                "(--preset is an experiment's protocol, in `nerfaug run` and `nerfaug study`)"
            )


def command(name: str):
    """The function or class of the command `name` (`COMMANDS`), its module imported now, its
    docstring reflowed for the help."""
    module, _, function = COMMANDS[name].partition(":")
    found = getattr(importlib.import_module(module), function)
    found.__doc__ = reflow(found.__doc__)
    return found


@dataclass
class _Preset:
    """The one option a preset command's first look at the command line reads."""

    preset: str | None = None


def parse(target, argv: list[str], prog: str):
    """tyro's parse of `argv` for the command `target`. A command with presets (a class with
    `PRESETS` and `from_preset`) is parsed twice: first for `--preset` alone, then in full with
    that preset's options as the default, so an option given changes the preset's value and one not
    given keeps it. An unknown preset name starts from the default one, and the full parse refuses it.
    The settings the options make (`nerfaug.schema.Settings`) are checked once tyro has built them,
    so that a refusal is the command's one line."""
    if not hasattr(target, "from_preset"):
        return built_then_checked(lambda: tyro.cli(target, args=argv, prog=prog))
    given, _ = tyro.cli(_Preset, args=argv, prog=prog, return_unknown_args=True, add_help=False)
    name = given.preset if given.preset in target.PRESETS else target.preset
    return built_then_checked(lambda: tyro.cli(target, args=argv, prog=prog, default=target.from_preset(name)))


def _dispatch(argv: list[str]) -> None:
    if argv[:1] == ["scene"]:
        scenes = importlib.import_module("nerfaug.cli.scene").COMMANDS
        for function in scenes.values():
            function.__doc__ = reflow(function.__doc__)
        tyro.extras.subcommand_cli_from_dict(scenes, args=argv[1:], prog="nerfaug scene")
        return
    if argv and argv[0] in COMMANDS:  # only this command's module is imported
        _check_renamed(argv)
        target, prog, args = command(argv[0]), f"nerfaug {argv[0]}", argv[1:]
        if argv[0] in ENGINE_COMMANDS:  # --engine.GROUP.SETTING: read apart (`nerfaug.cli.engine_options`)
            settings, args = split_engine_options(args)
            given = {} if wants_help(argv) else engine_settings_given(settings, prog)
            if not isinstance(target, type):
                target = functools.partial(target, engine_settings=given)
        parsed = parse(target, args, prog)
        if isinstance(target, type):  # a command's options as a dataclass: run them
            if argv[0] in ENGINE_COMMANDS:
                parsed = dataclasses.replace(parsed, engine_settings=given)
            parsed()
        return
    if argv and argv[0] not in ("-h", "--help"):
        raise SystemExit(f"{unknown('command', argv[0], COMMANDS)} (`nerfaug --help`)")
    # The overview imports no command's module: each loads what its own options need (some, torch).
    print(__doc__.strip())
    print()
    print(f"usage: nerfaug [-h] {{{','.join(COMMANDS)}}}")
    print()
    print("Choose which views to add when a NeRF has too little data. `nerfaug COMMAND --help`: its options.")
    if not argv:
        raise SystemExit("give a command (`nerfaug --help` lists them)")
    raise SystemExit(0)


if __name__ == "__main__":
    main()

"""The `nerfaug` command: scenes, experiments, reports, and the active-capture loop.

nerfaug scene render lego --out data/lego      render a built-in scene as a Blender dataset
nerfaug scene prepare DOWNLOAD --out data/mic  ready a downloaded dataset (NeRF-synthetic, LLFF, DTU)
nerfaug run --preset quick --out results/quick  the paper's experiment, then its report
nerfaug report results/quick                    (re)write report.md and report.html
nerfaug study --out results/study               which method wins where, on which engine
nerfaug methods                                 list the view-selection methods
nerfaug train DATA --out RUN                    active capture: train on what you have,
nerfaug propose RUN --n 6 --out poses.json      ask where to look next,
nerfaug add RUN --images DIR --poses poses.json add what you captured, and go on training
nerfaug export RUN --format nerfstudio --out DIR
nerfaug eval RUN --data DATA --split test       PSNR/SSIM/LPIPS of the session on held-out views
"""

from __future__ import annotations

import inspect
import os
import re
import sys
import warnings
from pathlib import Path
from typing import Annotated, Literal, get_args

import tyro

from nerfaug.cli_options import COMMAND_LINE, given_fields
from nerfaug.experiment.config import PresetName
from nerfaug.experiment.config import preset as make_preset
from nerfaug.nerf.config import EnginePreset
from nerfaug.selection.config import SelectionConfig

Positional = tyro.conf.Positional
# The defaults `--selection.*` options start from (read-only use: never mutated).
DEFAULT_SELECTION = SelectionConfig()


def preset_default(name: str) -> str:
    """The help's default for an option whose value `--preset` decides: each preset's, e.g.
    "(default: the preset's: quick, ablation: 5; paper: 10; tiny: 2)"."""
    presets: dict[str, list[str]] = {}
    for preset_name in get_args(PresetName):
        value = getattr(make_preset(preset_name), name)
        presets.setdefault(" ".join(map(str, value)) if isinstance(value, tuple) else str(value), []).append(
            preset_name
        )
    if len(presets) == 1:
        return f"(default: {next(iter(presets))}, in every preset)"
    return "(default: the preset's: " + "; ".join(f"{', '.join(p)}: {v}" for v, p in presets.items()) + ")"


def _from_preset(kind, name: str, metavar: str):
    return Annotated[kind | None, tyro.conf.arg(metavar=metavar, help_behavior_hint=preset_default(name))]


ENGINES = "{" + ",".join(get_args(EnginePreset)) + "}"
Scenes = _from_preset(tuple[str, ...], "scenes", "SCENE [SCENE ...]")
Methods = _from_preset(tuple[str, ...], "methods", "METHOD [METHOD ...]")
Trials = _from_preset(int, "trials", "INT")
Steps = _from_preset(int, "steps", "INT")
Engine = _from_preset(EnginePreset, "engine", ENGINES)
Resolution = _from_preset(int, "resolution", "INT")
Seed = _from_preset(int, "seed", "INT")
Data = Annotated[Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: the preset's scenes)")]
Workers = Annotated[
    int | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: one run per core; one at a time on a GPU)")
]
Address = Annotated[str | None, tyro.conf.arg(metavar="ADDRESS", help_behavior_hint="(default: a local Ray instance)")]


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


def run(
    out: Path = Path("results/quick"),
    preset: PresetName = "quick",
    scenes: Scenes = None,
    data: Data = None,
    methods: Methods = None,
    trials: Trials = None,
    steps: Steps = None,
    engine: Engine = None,
    resolution: Resolution = None,
    seed: Seed = None,
    backend: Literal["local", "ray"] = "local",
    workers: Workers = None,
    address: Address = None,
    force: bool = False,
    report: bool = True,
    device: Literal["auto", "cpu", "cuda"] = "auto",
    selection: SelectionConfig = DEFAULT_SELECTION,
) -> None:
    """Run the paper's experiment (scenes x methods x trials), then write its report.

    Re-running the same command skips completed runs; killing it loses at most the runs in flight.

    Args:
        out: results folder.
        preset: the protocol the other options change: quick (lego at 100x100 on the CPU, minutes),
            paper (Sec. IV: three scenes, 10 trials, 10k steps), ablation (Tables I and II), tiny
            (seconds; a smoke test).
        scenes: built-in scene names or dataset folders.
        data: a Blender-format dataset folder to run on (its train split is the candidate pool,
            its test split the evaluation); shorthand for --scenes DATA.
        methods: selection methods (see `nerfaug methods`); the first is compared with the others.
        trials: trials per (scene, method); trial k uses seed + k.
        steps: training steps per run.
        engine: NeRF engine preset.
        resolution: image size of built-in scenes (or the width user data is downscaled to).
        seed: base seed.
        backend: local (this machine) or ray (one task per run; --address joins a cluster).
        workers: concurrent runs (local backend) or Ray CPUs to start (local Ray).
        address: the Ray cluster to join.
        force: move the runs already in --out aside (into OUT/superseded/, nothing is deleted) and
            redo every run; needed when OUT's sweep.json is missing or its settings differ.
        report: write report.md / report.html at the end.
        device: where runs train, select and evaluate: auto (cuda when this machine has a GPU,
            else cpu), cpu or cuda. Part of the results' fingerprint (the numbers differ).
        selection: options of the selection methods (every one is part of the results'
            fingerprint); those given here replace the preset's, and a method's own settings (e.g.
            ours-authors') apply over them.
    """
    from dataclasses import replace

    from nerfaug.device import resolve_device
    from nerfaug.experiment.config import preset as make_preset
    from nerfaug.experiment.sweep import run_sweep

    config = make_preset(preset)
    changes = {
        k: v
        for k, v in dict(
            methods=methods, trials=trials, steps=steps, engine=engine, resolution=resolution, seed=seed
        ).items()
        if v is not None
    }
    if data is not None:  # a path, never taken for a built-in scene of the same name
        changes["scenes"] = (str(data) if data.is_absolute() else os.path.join(".", data),)
    elif scenes is not None:
        changes["scenes"] = scenes
    # auto is decided here, once, so every run (and the fingerprint) sees the same device.
    try:
        changes["device"] = resolve_device(device).type
    except ValueError as error:
        raise SystemExit(f"--device: {error}") from None
    changes["selection"] = replace(config.selection, **given_fields(selection, "selection", COMMAND_LINE.get()))
    config = config.replace(**changes)
    if workers is None:
        # One run per core on a CPU; on a GPU one run at a time (each holds its own CUDA context).
        workers = 1 if config.device == "cuda" else max(1, (os.cpu_count() or 1) // config.threads_per_run)
    try:
        outcome = run_sweep(
            config,
            out,
            backend=backend,
            workers=workers,
            address=address,
            force=force,
            command=["nerfaug", *sys.argv[1:]],
        )
    except KeyboardInterrupt:
        from nerfaug.errors import Interrupted
        from nerfaug.experiment.store import finished_runs

        raise Interrupted(
            f"{out}: interrupted; its {len(finished_runs(out))} finished run(s) are kept; re-run the "
            "same command to resume"
        ) from None
    if report:
        from nerfaug.report import write_report

        paths = write_report(out, paper_tables())
        print("report: " + ", ".join(str(p) for p in paths))
    if outcome.failed:
        print(f"{len(outcome.failed)} run(s) failed; re-run the same command to retry them:", file=sys.stderr)
        for key, why in outcome.failed.items():
            print(f"  {key}: {why}", file=sys.stderr)
        raise SystemExit(1)


def paper_tables():
    """The rows of the paper's ablation tables as the method registry defines them, and its
    protocol's image side (the experiments' paper preset): what a report compares with the paper,
    as `nerfaug.report.PaperTables`."""
    from nerfaug.report import PaperTables
    from nerfaug.selection import TABLE_I_ROWS, TABLE_II_ROWS

    return PaperTables(TABLE_I_ROWS, TABLE_II_ROWS, make_preset("paper").resolution)


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


def main(argv: list[str] | None = None) -> None:
    """The `nerfaug` command. Errors end as one line on stderr (exit 2: bad input, 1: failure,
    130: Ctrl-C); `--debug` or NERFAUG_DEBUG=1 shows the traceback instead."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv or os.environ.get("NERFAUG_DEBUG", "") not in ("", "0")
    argv = [arg for arg in argv if arg != "--debug"]
    # Flushing denormals (configure_process) makes numpy warn, once per float type, that the
    # smallest subnormal is zero: expected, and eight lines of noise before any one-line error.
    warnings.filterwarnings("ignore", message="The value of the smallest subnormal", category=UserWarning)
    try:
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
    except KeyboardInterrupt:
        if debug:
            raise
        print("nerfaug: interrupted; files already written are kept (finished runs, saved sessions)", file=sys.stderr)
        raise SystemExit(130) from None
    except Exception as error:
        if debug:
            raise
        print(f"nerfaug: {one_line(error)}", file=sys.stderr)
        raise SystemExit(exit_code(error)) from None


def scene() -> None:
    """Scenes: `nerfaug scene render SCENE --out DIR` renders a built-in scene (lego, chair,
    materials, cow) or a .blend file as a Blender-format dataset; `nerfaug scene prepare SOURCE
    --out DIR` readies a downloaded dataset (NeRF-synthetic, LLFF, DTU) for experiments (`--help`
    of each)."""
    _dispatch(["scene", "--help"])


def _dispatch(argv: list[str]) -> None:
    from nerfaug import session_cli
    from nerfaug.study_cli import study

    commands = {"scene": scene, "run": run, "report": report, "methods": methods, "study": study}
    commands.update(session_cli.COMMANDS)
    for command in [*commands.values(), scene_render, scene_prepare]:
        command.__doc__ = reflow(command.__doc__)
    if argv[:1] == ["scene"]:
        tyro.extras.subcommand_cli_from_dict(
            {"render": scene_render, "prepare": scene_prepare}, args=argv[1:], prog="nerfaug scene"
        )
        return
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        print()
    parsing = COMMAND_LINE.set(tuple(argv))
    try:
        tyro.extras.subcommand_cli_from_dict(
            commands,
            args=argv,
            prog="nerfaug",
            description="Choose which views to add when a NeRF has too little data.",
        )
    finally:
        COMMAND_LINE.reset(parsing)


if __name__ == "__main__":
    main()

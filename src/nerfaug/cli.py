"""The `nerfaug` command: scenes, experiments, reports, and the active-capture loop.

    nerfaug scene render lego --out data/lego      render a built-in scene as a Blender dataset
    nerfaug run --preset quick --out results/quick  the paper's experiment, then its report
    nerfaug report results/quick                    (re)write report.md and report.html
    nerfaug methods                                 list the view-selection methods
    nerfaug train DATA --out RUN                    active capture: train on what you have,
    nerfaug propose RUN --n 6 --out poses.json      ask where to look next,
    nerfaug add RUN --images DIR --poses poses.json add what you captured, and go on training
    nerfaug export RUN --format nerfstudio --out DIR
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated, Literal

import tyro

Positional = tyro.conf.Positional


def scene_render(
    scene: Positional[str],
    out: Path,
    res: int = 200,
    pool: int = 300,
    test: int = 200,
    initial: int = 6,
    samples: int = 16,
    seed: int = 0,
) -> None:
    """Render a built-in scene (lego, chair, materials) or a .blend file as a Blender-format dataset.

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

    path = render_scene_dataset(scene, out, resolution=res, pool=pool, test=test, initial=initial,
                                samples=samples, seed=seed, progress=True)
    print(f"dataset written to {path}")


def run(
    out: Path = Path("results/quick"),
    preset: Literal["quick", "paper", "ablation", "tiny"] = "quick",
    scenes: tuple[str, ...] | None = None,
    data: Path | None = None,
    methods: tuple[str, ...] | None = None,
    trials: int | None = None,
    steps: int | None = None,
    engine: Literal["cpu", "paper", "test"] | None = None,
    resolution: int | None = None,
    seed: int | None = None,
    backend: Literal["local", "ray"] = "local",
    workers: int | None = None,
    address: str | None = None,
    force: bool = False,
    report: bool = True,
) -> None:
    """Run the paper's experiment (scenes x methods x trials), then write its report.

    Re-running the same command skips completed runs; killing it loses at most the runs in flight.

    Args:
        out: results folder.
        preset: quick (default; lego at 100x100 on the CPU, minutes), paper (Sec. IV: three scenes,
            10 trials, 10k steps), ablation (Tables I and II), tiny (seconds; smoke test).
        scenes: built-in scene names or dataset folders (overrides the preset's).
        data: a Blender-format dataset folder to run on (its train split is the candidate pool,
            its test split the evaluation); shorthand for --scenes DATA.
        methods: selection methods (see `nerfaug methods`); the first is compared with the others.
        trials: trials per (scene, method); trial k uses seed + k.
        steps: training steps per run.
        engine: NeRF engine preset.
        resolution: image size of built-in scenes (or the width user data is downscaled to).
        seed: base seed.
        backend: local (this machine) or ray (one task per run; --address joins a cluster).
        workers: concurrent runs (local backend) or Ray CPUs to start (local Ray); default: one
            run per core.
        address: Ray cluster address; omitted starts a local Ray instance.
        force: discard existing results in --out and redo every run.
        report: write report.md / report.html at the end.
    """
    from nerfaug.experiment.config import preset as make_preset
    from nerfaug.experiment.sweep import run_sweep

    config = make_preset(preset)
    changes = {k: v for k, v in dict(methods=methods, trials=trials, steps=steps, engine=engine,
                                      resolution=resolution, seed=seed).items() if v is not None}
    if data is not None:
        changes["scenes"] = (str(data),)
    elif scenes is not None:
        changes["scenes"] = scenes
    config = config.replace(**changes)
    if workers is None:
        workers = max(1, (os.cpu_count() or 1) // config.threads_per_run)
    outcome = run_sweep(config, out, backend=backend, workers=workers, address=address, force=force,
                        command=["nerfaug", *sys.argv[1:]])
    if report:
        from nerfaug.report import write_report

        paths = write_report(out)
        print("report: " + ", ".join(str(p) for p in paths))
    if outcome.failed:
        print(f"{len(outcome.failed)} run(s) failed; re-run the same command to retry them:", file=sys.stderr)
        for key, why in outcome.failed.items():
            print(f"  {key}: {why}", file=sys.stderr)
        raise SystemExit(1)


def report(results: Positional[Path]) -> None:
    """Write report.md and a self-contained report.html for a results folder.

    Args:
        results: the folder `nerfaug run --out` wrote.
    """
    from nerfaug.report import ReportError, write_report

    try:
        paths = write_report(results)
    except ReportError as error:
        raise SystemExit(f"nerfaug report: {error}")
    for path in paths:
        print(path)


def methods() -> None:
    """List the view-selection methods and what each does."""
    from nerfaug.selection import METHODS

    width = max(len(name) for name in METHODS)
    for name, spec in METHODS.items():
        print(f"{name:<{width}}  {spec.description}")


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = {
        "run": run, "report": report, "methods": methods,
    }
    from nerfaug import session_cli

    commands.update(session_cli.COMMANDS)
    if argv[:1] == ["scene"]:
        tyro.extras.subcommand_cli_from_dict({"render": scene_render}, args=argv[1:], prog="nerfaug scene")
        return
    descriptions = {"scene": "Built-in scenes: `nerfaug scene render --help`."}
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        print()
    tyro.extras.subcommand_cli_from_dict(
        commands, args=argv, prog="nerfaug",
        description="Choose which views to add when a NeRF has too little data. " + descriptions["scene"],
    )


if __name__ == "__main__":
    main()

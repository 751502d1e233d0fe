"""The `nerfaug run` command: the paper's experiment (scenes x methods x trials) over a preset,
then its report. Its options' help shows each experiment preset's values, so importing this
module reads the presets (and the selection methods' registry): `nerfaug.cli` imports it only when
`nerfaug run` is the command.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated, Literal, get_args

import tyro

from nerfaug.cli_options import COMMAND_LINE, given_fields
from nerfaug.experiment.config import PROTOCOL_PRESETS, PresetName
from nerfaug.nerf.config import EnginePreset
from nerfaug.selection.config import SelectionConfig

# The defaults `--selection.*` options start from (read-only use: never mutated).
DEFAULT_SELECTION = SelectionConfig()


def preset_default(name: str) -> str:
    """The help's default for an option whose value `--preset` decides: each preset's, e.g.
    "(default: the preset's: quick, ablation: 5; paper: 10; tiny: 2)"."""
    presets: dict[str, list[str]] = {}
    for preset_name in get_args(PresetName):
        value = getattr(PROTOCOL_PRESETS[preset_name], name)
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
        preset: the experiment's protocol, which the other options change: quick (lego at 100x100 on the CPU, minutes),
            paper (Sec. IV: three scenes, 10 trials, 10k steps), ablation (Tables I and II), tiny
            (seconds; a smoke test).
        scenes: built-in scene names or dataset folders.
        data: a Blender-format dataset folder to run on (its train split is the candidate pool,
            its test split the evaluation); shorthand for --scenes DATA.
        methods: selection methods (see `nerfaug methods`); the first is compared with the others.
        trials: trials per (scene, method); trial k uses seed + k.
        steps: training steps per run.
        engine: the NeRF engine preset (the names `nerfaug train --engine` takes).
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

    from nerfaug.cli import paper_tables
    from nerfaug.device import resolve_device
    from nerfaug.experiment.sweep import run_sweep

    config = PROTOCOL_PRESETS.choose(preset)
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
    print(run_size_line(config, out, workers), flush=True)
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


def run_size_line(config, out: Path, workers: int) -> str:
    """How many runs `config` makes, how big, and about how long on this device (`nerfaug.run_size`)."""
    from nerfaug.experiment.store import finished_runs
    from nerfaug.run_size import per_cell, size_line
    from nerfaug.scenes.builtin import BUILTIN_SCENES

    total = len(config.scenes) * len(config.methods) * config.trials
    finished = min(len(finished_runs(out)), total) if Path(out).is_dir() else 0
    shape = " x ".join(
        (
            per_cell(len(config.scenes), "scene"),
            per_cell(len(config.methods), "method"),
            per_cell(config.trials, "trial"),
        )
    )
    builtin = sum(scene in BUILTIN_SCENES for scene in config.scenes)
    views = config.pool + config.n_test + config.n_initial
    return size_line(
        "nerfaug run",
        {config.engine: total - finished},
        finished,
        shape,
        config.resolution,
        config.steps,
        config.n_test,
        config.device,
        workers,
        render=(builtin, views),
    )

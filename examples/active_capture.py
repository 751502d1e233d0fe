"""Active capture in a loop: train on the views you have, ask where to look next, capture there,
add the images, train on. The "robot" here is simulated: Blender renders the proposed poses of a
built-in scene (or, with `--capture pool`, they are looked up among pre-rendered views, which is
fast and needs no Blender after the dataset exists).

    python examples/active_capture.py                        # lego at 100x100, 2 rounds of 6 views
    python examples/active_capture.py --data path/to/blender_dataset --split train --capture pool \
        --run results/my-capture --export results/my-capture-export
    python examples/active_capture.py --engine test --steps-per-round 20 --n-candidates 20 \
        --run results/quick-capture --export results/quick-capture-export                # seconds

Every step is one call on a `CaptureSession`; the run folder can be reopened at any point with
`CaptureSession.open(run)` or driven from the shell (`nerfaug propose RUN`, `nerfaug add RUN`).
Run again with the same options, it goes on with the session in `--run`; with other settings
(dataset, split, engine, seed) it refuses, naming them: each setting has its own run folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import tyro

from nerfaug.capture import SESSION_FILE, ProposalRequest, SessionSettings, SessionState
from nerfaug.session import CaptureSession


def dataset(data: Path | None, scene: str, resolution: int, pool: int) -> Path:
    """The dataset to start from: `data` as given (it must exist), or by default the built-in
    scene in data/SCENE-RESOLUTION: used as it is when there, else rendered there as `nerfaug
    scene render SCENE --out data/SCENE-RESOLUTION --res RESOLUTION` renders it (the README's
    commands use the same folder)."""
    if data is not None:
        if not data.is_dir():
            raise SystemExit(f"--data {data}: no such folder; give a Blender dataset, or leave --data out")
        return data
    data = Path(f"data/{scene}-{resolution}")
    if data.is_dir():
        print(f"using the dataset already in {data} (--data: another one)")
        return data
    from nerfaug.scenes import render_scene_dataset

    return render_scene_dataset(scene, data, resolution=resolution, pool=pool)


def open_or_create(run: Path, data: Path, engine: str, seed: int, split: str) -> CaptureSession:
    """A new session in `run`, or the one already there when it was made with these settings;
    refused, naming what differs, when it was not."""
    if not (run / SESSION_FILE).exists():
        return CaptureSession.create(data, run, SessionSettings(engine=engine, seed=seed), split=split, progress=True)
    state = SessionState.read(run)
    wanted = {"--data": str(data.resolve()), "--split": split, "--engine": engine, "--seed": seed}
    source = state.source
    found = {"--data": source.data_dir, "--split": source.split, "--engine": state.engine, "--seed": state.seed}
    differ = [f"{name} {found[name]} (asked: {wanted[name]})" for name in wanted if found[name] != wanted[name]]
    if differ:
        raise SystemExit(
            f"{run} holds a session made with {', '.join(differ)}; give another --run (and --export) "
            "for these settings, or the session's own"
        )
    session = CaptureSession.open(run, progress=True)
    print(f"going on with the session in {run} (same settings): step {session.step}, {len(session.cameras)} views")
    return session


def main(
    data: Path | None = None,
    scene: str = "lego",
    split: str = "initial",
    run: Path = Path("results/active-capture"),
    export: Path = Path("results/active-capture-export"),
    capture: Literal["blender", "pool"] = "blender",
    rounds: int = 2,
    views_per_round: int = 6,
    steps_per_round: int = 500,
    n_candidates: int = 500,
    engine: Literal["nerfacto-cpu", "cpu", "paper", "test"] = "nerfacto-cpu",
    seed: int = 0,
    resolution: int = 100,
    pool: int = 300,
    allow_empty: bool = False,
) -> None:
    """Run `rounds` of train -> propose -> capture -> add, then export for nerfstudio.

    Args:
        data: a Blender-format dataset folder; by default data/SCENE-RESOLUTION, the built-in
            `scene` rendered there when absent.
        scene: the built-in scene (lego, chair, materials) the simulated robot captures.
        split: the dataset split with the views captured so far ("initial": 6 views on one half).
        run: the run folder (model, grown dataset, proposals, maps).
        export: where the grown dataset is written for nerfstudio (outside the run folder).
        capture: "blender" renders any proposed pose live; "pool" chooses among the dataset's
            train split (the poses such a robot can reach) and takes their pre-rendered images.
        rounds: propose-capture-add rounds.
        views_per_round: views proposed per round.
        steps_per_round: training steps before each proposal (and after the last).
        n_candidates: hemisphere candidates scored per proposal (with `--capture blender`).
        engine: the NeRF engine.
        seed: seeds the model, its training and every proposal.
        resolution, pool: image size and candidate pool of the dataset when it is rendered here.
        allow_empty: propose even from a NeRF that learned nothing yet (a run of a few steps).
    """
    data = dataset(data, scene, resolution, pool)
    session = open_or_create(run, data, engine, seed, split)
    print(f"{len(session.trainer.train_views)} views; hemisphere {session.hemisphere}")

    if capture == "pool":
        from nerfaug.data import load_dataset
        from nerfaug.oracle import PoolOracle

        pool = load_dataset(data, "train")
        robot, reachable = PoolOracle(pool), pool.cameras.camera_to_world
    else:
        from nerfaug.oracle import BlenderOracle

        k = session.template()
        robot = BlenderOracle(scene, k.width, k.height, float(k.camera_angle_x[0]))
        reachable = None  # anywhere on the hemisphere

    for _ in range(rounds):
        session.train(steps_per_round)
        request = ProposalRequest(
            n=views_per_round, method="ours", candidates=reachable, n_candidates=n_candidates, allow_empty=allow_empty
        )
        proposal = session.propose(request)
        print(f"proposal {proposal.number}: map {proposal.map_path}")
        proposal.write(run / f"poses_{proposal.number:03d}.json")  # what a real robot would get
        images = robot.capture(proposal.poses, proposal.names)  # ... and what it brings back
        session.add_views(images, proposal)
        session.save()

    session.train(steps_per_round)
    session.save()
    print(
        f"step {session.step}, {len(session.trainer.train_views)} views; exported to "
        f"{session.export(export, format='nerfstudio')}"
    )


if __name__ == "__main__":
    tyro.cli(main)

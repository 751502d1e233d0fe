"""Active capture in a loop: train on the views you have, ask where to look next, capture there,
add the images, train on. The "robot" here is simulated: Blender renders the proposed poses of a
built-in scene (or, with `--capture pool`, they are looked up among pre-rendered views, which is
fast and needs no Blender after the dataset exists).

    python examples/active_capture.py                        # lego at 100x100, 2 rounds of 6 views
    python examples/active_capture.py --data path/to/blender_dataset --split train --capture pool
    python examples/active_capture.py --preset test --steps-per-round 20 --n-candidates 20   # seconds

Every step is one call on a `CaptureSession`; the run folder can be reopened at any point with
`CaptureSession.open(run)` or driven from the shell (`nerfaug propose RUN`, `nerfaug add RUN`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import tyro

from nerfaug.session import CaptureSession


def main(
    data: Path = Path("data/lego-100"),
    scene: str = "lego",
    split: str = "initial",
    run: Path = Path("results/active-capture"),
    export: Path = Path("results/active-capture-export"),
    capture: Literal["blender", "pool"] = "blender",
    rounds: int = 2,
    views_per_round: int = 6,
    steps_per_round: int = 500,
    n_candidates: int = 500,
    preset: Literal["cpu", "paper", "test"] = "cpu",
    seed: int = 0,
    resolution: int = 100,
    pool: int = 200,
) -> None:
    """Run `rounds` of train -> propose -> capture -> add, then export for nerfstudio.

    Args:
        data: a Blender-format dataset; rendered from `scene` first if it does not exist.
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
        preset: NeRF engine preset.
        seed: seeds the model, its training and every proposal.
        resolution, pool: image size and candidate pool of `data` when it is rendered here.
    """
    if not data.exists():
        from nerfaug.scenes import render_scene_dataset

        render_scene_dataset(scene, data, resolution=resolution, pool=pool, test=20, initial=6)

    session = (
        CaptureSession.open(run)
        if (run / "session.json").exists()
        else CaptureSession.create(data, run, preset=preset, seed=seed, split=split, progress=True)
    )
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
        proposal = session.propose(views_per_round, method="ours", candidates=reachable, n_candidates=n_candidates)
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

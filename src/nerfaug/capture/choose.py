"""How a session chooses its next views: the candidate cameras, the selection method's call, and
the proposal's record (what `CaptureSession.propose` does; `proposal` holds what it returns)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture.constraints import ViewConstraints, constrained_indices
from nerfaug.capture.frame import ENGINE_RADIUS
from nerfaug.capture.images import as_array
from nerfaug.capture.proposal import Proposal, proposal_seed, read_poses
from nerfaug.capture.state import PROPOSALS_DIR, ProposalRecord, now
from nerfaug.data.frames import check_pose
from nerfaug.selection.candidates import with_poses


def check_method(method: str) -> None:
    """Raise ValueError unless `method` names a selection method."""
    from nerfaug.selection import METHODS

    if method not in METHODS:
        raise ValueError(
            f"unknown selection method {method!r}; choose one of {', '.join(METHODS)} "
            "(`nerfaug methods` describes them)"
        )


def describe_candidates(candidates) -> str:
    """How session.json names the candidates of a proposal."""
    if candidates is None or (isinstance(candidates, str) and candidates == "hemisphere"):
        return "hemisphere"
    if isinstance(candidates, (str, Path)):
        return str(candidates)
    return "given"


def candidate_cameras(
    session, candidates=None, n_candidates: int = 500, generator: torch.Generator | None = None
) -> Cameras:
    """`CaptureSession.candidate_cameras`: world-frame candidates minus the poses trained on."""
    from nerfaug.selection import hemisphere_candidates, matching_poses

    session.require_model()
    template = session.template()
    engine_train = session.trainer.train_views.cameras.to("cpu")
    if candidates is None or (isinstance(candidates, str) and candidates == "hemisphere"):
        engine = hemisphere_candidates(
            session.template(engine_train.width, engine_train.height),
            n_candidates,
            generator,
            radius=ENGINE_RADIUS,
            training=engine_train,
        )
        return with_poses(template, session.hemisphere.to_world(engine.camera_to_world))
    if isinstance(candidates, Cameras):
        given = candidates
    elif isinstance(candidates, (str, Path)):
        given = with_poses(template, read_poses(candidates)[0])
    else:
        poses = np.asarray(as_array(candidates), dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise ValueError(f"candidate poses must have shape (n, 4, 4), got {poses.shape}")
        given = with_poses(
            template, torch.stack([check_pose(p, Path("candidates"), f"candidates[{i}]") for i, p in enumerate(poses)])
        )
    # Compared in the engine frame, so the tolerance does not depend on the data's units.
    known = matching_poses(session.hemisphere.to_engine(given.camera_to_world), engine_train.camera_to_world)
    return given[torch.nonzero(~known).reshape(-1).tolist()]


def propose(
    session,
    n: int = 6,
    method: str = "ours",
    candidates=None,
    n_candidates: int = 500,
    generator: torch.Generator | None = None,
    seed: int | None = None,
    config=None,
    map: bool = True,
    constraints: ViewConstraints | dict | None = None,
) -> Proposal:
    """`CaptureSession.propose`: choose, record and write `n` views to capture next."""
    session.require_model()
    from nerfaug.selection import SelectionConfig, get_method, select_views

    check_method(method)
    if isinstance(config, dict):
        config = SelectionConfig.from_dict(config)
    used_config = get_method(method).effective_config(config)
    if int(n) < 1 or int(n) != n:
        raise ValueError(f"n (views to propose) must be an integer >= 1, got {n}")
    if int(n_candidates) < 1:
        raise ValueError(f"n_candidates must be >= 1, got {n_candidates}")
    if seed is not None and int(seed) < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    if isinstance(constraints, dict):
        constraints = ViewConstraints.from_dict(constraints)
    elif constraints is not None:
        constraints.check()
    number = len(session.state.proposals)
    used_seed = None
    if generator is None:
        used_seed = proposal_seed(session.seed, number) if seed is None else int(seed)
        generator = torch.Generator().manual_seed(used_seed)
    world = candidate_cameras(session, candidates, n_candidates, generator)
    world = world[constrained_indices(world.camera_to_world, session.hemisphere, constraints, n).tolist()]
    if len(world) < n:
        raise ValueError(
            f"{describe_candidates(candidates)}: cannot propose {n} views from {len(world)} candidates "
            "(poses the model already trains on are left out); ask for fewer views or give more "
            "candidates"
        )
    hemisphere = session.hemisphere
    engine_train = session.trainer.train_views.cameras
    engine = hemisphere.cameras_to_engine(world)
    if (engine.width, engine.height) != (engine_train.width, engine_train.height):
        engine = engine.resized(engine_train.width, engine_train.height)
    selection = select_views(
        method, session.trainer.model, engine_train, engine.to(session.trainer.device), n, generator, config
    )
    chosen = selection.indices.long()
    poses = world.camera_to_world[chosen]
    azimuth, polar, _ = hemisphere.angles(poses)
    names = [f"capture_{number:03d}_{i:02d}" for i in range(n)]
    folder = session.run_dir / PROPOSALS_DIR
    map_path = None
    if map:
        from nerfaug.maps import plot_hemisphere_map

        map_path = plot_hemisphere_map(
            engine.camera_to_world,
            selection.scores,
            engine_train.camera_to_world.cpu(),
            engine.camera_to_world[chosen],
            path=folder / f"proposal_{number:03d}.png",
            title=f"proposal {number}: {method} at step {session.step}",
        )
    angle_x = float(world.camera_angle_x[0])
    proposal = Proposal(
        number,
        selection.method or method,
        poses,
        names,
        azimuth,
        polar,
        chosen,
        world,
        selection.scores.float(),
        dict(selection.components),
        map_path,
        session.step,
        used_seed,
        angle_x,
        hemisphere,
    )
    record_path = proposal.write(folder / f"proposal_{number:03d}.json", include_candidates=True)
    session.state.proposals.append(
        ProposalRecord(
            number=number,
            method=proposal.method,
            n=n,
            step=session.step,
            seed=used_seed,
            candidates=describe_candidates(candidates),
            n_candidates=len(world),
            names=names,
            poses=poses.tolist(),
            azimuth=azimuth.tolist(),
            polar=polar.tolist(),
            file=str(record_path.relative_to(session.run_dir)),
            created=now(),
            extra={"selection": used_config.to_dict()}
            | ({} if constraints is None or constraints.empty else {"constraints": constraints.to_dict()}),
        )
    )
    return proposal

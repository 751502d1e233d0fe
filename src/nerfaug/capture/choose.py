"""The steps of a session's proposal around the selection itself (`CaptureSession.propose` calls
`select_views` between them): its random source, the candidate cameras its constraints allow, the
proposal a selection makes among them (with its hemisphere map), and the proposal's record. Each
step takes only the fields of the request (`ProposalRequest`) it needs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture.constraints import constrained_indices
from nerfaug.capture.model import SessionModel
from nerfaug.capture.proposal import Proposal, proposal_seed, read_poses
from nerfaug.capture.proposal_request import ViewConstraints
from nerfaug.capture.state import ProposalRecord, now
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import check_pose
from nerfaug.data.world_frame import ENGINE_RADIUS
from nerfaug.maps import plot_hemisphere_map
from nerfaug.selection import Selection, hemisphere_candidates, matching_poses
from nerfaug.selection.candidates import with_poses


def _refuse_twice_named(path, names: list[str]) -> None:
    """A pool names each view once: a name twice would be proposed twice, and `add` takes one image
    for both."""
    first: dict[str, int] = {}
    for i, name in enumerate(names):
        if name in first:
            twice = f"names the view {name!r} twice (frames[{first[name]}] too)"
            raise DatasetError(path, twice, field=f"frames[{i}].file_path", value=name)
        first[name] = i


def describe_candidates(candidates, pool: bool = False) -> str:
    """How session.json names the candidates of a proposal: hemisphere, the session's pool, the
    file, or given."""
    if pool:
        return "pool"
    if candidates is None:
        return "hemisphere"
    return str(candidates) if isinstance(candidates, Path) else "given"


def candidate_cameras(
    model: SessionModel, candidates=None, n_candidates: int = 500, generator: torch.Generator | None = None
) -> Cameras:
    """World-frame candidate cameras minus the poses trained on: `n_candidates` poses uniform on
    the session's hemisphere (None; a sparse start's pool, where the session has one), or a
    `ProposalRequest`'s checked reachable poses (a list of 4x4, or a transforms JSON `Path`), with
    the session's intrinsics."""
    return named_candidates(model, candidates, n_candidates, generator)[0]


def named_candidates(
    model: SessionModel, candidates=None, n_candidates: int = 500, generator: torch.Generator | None = None
) -> tuple[Cameras, list[str] | None]:
    """`candidate_cameras`, and the names of the pool's views (None for other candidates)."""
    template, hemisphere = model.template, model.hemisphere
    engine_train = model.train_cameras.to("cpu")
    names = None
    if candidates is None and model.pool is not None:
        poses, names = read_poses(model.pool)
        _refuse_twice_named(model.pool, names)
        given = with_poses(template, poses)
    elif candidates is None:
        engine = hemisphere_candidates(
            template.resized(engine_train.width, engine_train.height),
            n_candidates,
            generator,
            radius=ENGINE_RADIUS,
            training=engine_train,
        )
        return with_poses(template, hemisphere.to_world(engine.camera_to_world)), None
    elif isinstance(candidates, Path):
        given = with_poses(template, read_poses(candidates)[0])
    else:
        poses = np.asarray(candidates, dtype=np.float64)
        given = with_poses(
            template, torch.stack([check_pose(p, Path("candidates"), f"candidates[{i}]") for i, p in enumerate(poses)])
        )
    # Compared in the engine frame, so the tolerance does not depend on the data's units.
    known = matching_poses(hemisphere.to_engine(given.camera_to_world), engine_train.camera_to_world)
    kept = torch.nonzero(~known).reshape(-1).tolist()
    return given[kept], None if names is None else [names[i] for i in kept]


@dataclass(frozen=True)
class Candidates:
    """The candidates a proposal chooses among, once the constraints have left out the others.

    Attributes:
        world: the world-frame cameras (n_candidates).
        names: the pool's names of them (a sparse start's pool), None for other candidates.
        described: how session.json names them ("hemisphere", "pool", a file, "given").
    """

    world: Cameras
    names: list[str] | None
    described: str


def proposal_generator(
    generator: torch.Generator | None, session_seed: int, number: int, asked: int | None
) -> tuple[torch.Generator, int | None]:
    """The random source of proposal `number`, and the seed it was made from: the caller's
    `generator` (seed None), else one seeded from the request's seed `asked`, else from the
    session's seed and the proposal's number (`proposal_seed`), so that a resumed session proposes
    exactly what the original would have."""
    if generator is not None:
        return generator, None
    seed = proposal_seed(session_seed, number) if asked is None else int(asked)
    return torch.Generator().manual_seed(seed), seed


def allowed_candidates(
    model: SessionModel,
    candidates,
    n_candidates: int,
    constraints: ViewConstraints | None,
    n: int,
    generator: torch.Generator,
) -> Candidates:
    """The candidates of a request (`named_candidates`) that its constraints allow.

    Raises:
        TooFewCandidates: the constraints leave fewer than `n`.
        ValueError: fewer than `n` candidates are left once the poses trained on are left out.
    """
    world, names = named_candidates(model, candidates, n_candidates, generator)
    allowed = constrained_indices(world.camera_to_world, model.hemisphere, constraints, n).tolist()
    described = describe_candidates(candidates, names is not None)
    if len(allowed) < n:
        raise ValueError(
            f"{described}: cannot propose {n} views from {len(allowed)} candidates (poses the model already "
            "trains on are left out); ask for fewer views or give more candidates"
        )
    return Candidates(world[allowed], None if names is None else [names[i] for i in allowed], described)


def engine_cameras(model: SessionModel, world: Cameras) -> Cameras:
    """World-frame candidates as the NeRF sees them: in its frame, at its training views' size."""
    trained = model.train_cameras
    engine = model.hemisphere.cameras_to_engine(world)
    if (engine.width, engine.height) != (trained.width, trained.height):
        engine = engine.resized(trained.width, trained.height)
    return engine


def proposal_of(
    selection: Selection,
    candidates: Candidates,
    engine: Cameras,
    model: SessionModel,
    number: int,
    seed: int | None,
    min_separation: float,
    map_path: Path | None,
) -> Proposal:
    """The proposal a selection makes among `candidates` (`engine`: the same in the NeRF's
    frame), and its hemisphere map of every candidate's score at `map_path` (None: no map)."""
    chosen = selection.indices.long()
    poses = candidates.world.camera_to_world[chosen]
    azimuth, polar, _ = model.hemisphere.angles(poses)
    if candidates.names is not None:  # the pool's own names: `add` takes the chosen images from the dataset by them
        names = [candidates.names[i] for i in chosen.tolist()]
    else:
        names = [f"capture_{number:03d}_{i:02d}" for i in range(len(chosen))]
    if map_path is not None:
        map_path = plot_hemisphere_map(
            engine.camera_to_world,
            selection.scores,
            model.train_cameras.camera_to_world.cpu(),
            engine.camera_to_world[chosen],
            path=map_path,
            title=f"proposal {number}: {selection.method} at step {model.step}",
            label=selection.score_label(selection.config),
        )
    return Proposal(
        number=number,
        method=selection.method,
        poses=poses,
        names=names,
        azimuth=azimuth,
        polar=polar,
        indices=chosen,
        candidates=candidates.world,
        scores=selection.scores.float(),
        components=dict(selection.components),
        map_path=map_path,
        step=model.step,
        seed=seed,
        camera_angle_x=float(candidates.world.camera_angle_x[0]),
        hemisphere=model.hemisphere,
        min_separation=min_separation,
        uniform_fill=selection.uniform_fill,
    )


def record_of(
    proposal: Proposal,
    file: str,
    described: str,
    selection: Selection,
    constraints: ViewConstraints | None,
    empty_model: bool,
) -> ProposalRecord:
    """What the session's history keeps of `proposal`, written to `file` (relative to the run);
    "empty_model": true when it was made, as asked, from an empty NeRF."""
    return ProposalRecord(
        number=proposal.number,
        method=proposal.method,
        n=len(proposal.names),
        step=proposal.step,
        seed=proposal.seed,
        candidates=described,
        n_candidates=len(proposal.candidates),
        names=proposal.names,
        poses=proposal.poses.tolist(),
        azimuth=proposal.azimuth.tolist(),
        polar=proposal.polar.tolist(),
        file=file,
        created=now(),
        selection=selection.config.to_dict(),
        **constraints_record(constraints),
        **separation_record(proposal.min_separation),
        **({"uniform_fill": proposal.uniform_fill} if proposal.uniform_fill else {}),
        **({"empty_model": True} if empty_model else {}),
    )


def separation_record(min_separation: float) -> dict:
    """What a proposal's record keeps of its minimum separation (degrees; 0 when switched off)."""
    return {"min_separation": float(min_separation)}


def constraints_record(constraints: ViewConstraints | None) -> dict:
    """What a proposal's record keeps of its constraints: nothing when there were none."""
    return {} if constraints is None or constraints.empty else {"constraints": constraints.to_dict()}

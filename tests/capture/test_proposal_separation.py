"""A session's proposals kept apart (`min_separation`, degrees): every two views of one proposal at
least that far apart about the hemisphere's centre, recorded with the proposal; 15 degrees by default,
0 switches it off."""

import json
import math
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from nerfaug.capture import CaptureSession, ProposalRequest, SessionFolder, SessionSettings
from nerfaug.cli import main
from nerfaug.selection import SelectionConfig

from .test_constraints import tiny_dataset

FAST = SelectionConfig(entropy_resolution=4)


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("separated")
    settings = SessionSettings(engine="test", seed=1, radius=4.03)
    session = CaptureSession.create(tiny_dataset(tmp / "data"), tmp / "run", settings)
    session.train(2)
    session.save()
    return tmp / "run"


def closest_pair_degrees(poses: torch.Tensor, centre) -> float:
    directions = poses[:, :3, 3].double() - torch.as_tensor(centre, dtype=torch.float64)
    directions = directions / directions.norm(dim=-1, keepdim=True)
    angles = torch.rad2deg(torch.arccos((directions @ directions.T).clamp(-1, 1)))
    angles.fill_diagonal_(math.inf)
    return float(angles.min())


def test_a_separated_proposal_keeps_its_views_apart_and_records_it(session_dir):
    session = CaptureSession.open(session_dir)
    proposal = session.propose(
        ProposalRequest(allow_empty=True, n=5, n_candidates=120, selection=FAST, min_separation=35.0), map=False
    )
    assert closest_pair_degrees(proposal.poses, session.hemisphere.centre) >= 35.0 - 1e-4
    assert session.proposals[-1].model_extra["min_separation"] == 35.0
    written = json.loads((session_dir / session.proposals[-1].file).read_text())
    assert written["nerfaug"]["min_separation"] == 35.0


def test_proposals_are_spread_by_default_and_zero_switches_it_off(session_dir):
    """By default no two views of a proposal lie within 15 degrees, and the choice is recorded;
    with the separation 0 the method's own draw comes back (here with views closer than that)."""
    request = ProposalRequest(allow_empty=True, n=6, n_candidates=120, selection=FAST, seed=0)
    session = CaptureSession.open(session_dir)
    spread = session.propose(request, map=False)
    centre = session.hemisphere.centre
    assert closest_pair_degrees(spread.poses, centre) >= 15.0 - 1e-4
    assert session.proposals[-1].model_extra["min_separation"] == 15.0
    assert spread.transforms()["nerfaug"]["min_separation"] == 15.0
    off = CaptureSession.open(session_dir).propose(replace(request, min_separation=0.0), map=False)
    assert closest_pair_degrees(off.poses, centre) < 15.0  # what the default prevents
    assert off.transforms()["nerfaug"]["min_separation"] == 0.0
    again = CaptureSession.open(session_dir).propose(replace(request, min_separation=0.0), map=False)
    assert torch.equal(off.indices, again.indices)


def test_nerfaug_propose_takes_a_minimum_separation(session_dir, tmp_path, capsys):
    out = tmp_path / "poses.json"
    args = [
        "propose",
        str(session_dir),
        "--allow-empty",
        "--out",
        str(out),
        "--n",
        "4",
        "--n-candidates",
        "100",
        "--device",
        "cpu",
    ]
    main([*args, "--min-separation", "40", "--selection.entropy-resolution", "4"])
    written = json.loads(out.read_text())
    poses = torch.tensor([frame["transform_matrix"] for frame in written["frames"]])
    centre = SessionFolder.open(session_dir).hemisphere.centre
    assert closest_pair_degrees(poses, centre) >= 40.0 - 1e-3
    assert written["nerfaug"]["min_separation"] == 40.0
    capsys.readouterr()
    with pytest.raises(SystemExit) as done:
        main([*args, "--force", "--min-separation", "200"])
    assert done.value.code == 2
    assert capsys.readouterr().err.strip() == "nerfaug: --min-separation 200: must be < 180"
    with pytest.raises(SystemExit) as done:
        main([*args, "--force", "--min-separation", "120", "--selection.entropy-resolution", "4"])
    assert done.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]  # after the scoring's progress lines
    assert err.startswith("nerfaug: cannot choose 4 views at least 120 degrees apart among 100 candidates")


def test_a_proposal_from_a_model_that_gives_no_information_says_how_many_views_are_uniform(session_dir, monkeypatch):
    """A NeRF that renders nothing gives FisherRF's gain 0 everywhere: the proposal still has its
    views, drawn uniformly, and its file and the session's history say how many."""
    from nerfaug.selection import registry
    from nerfaug.selection.interface import Estimate
    from nerfaug.selection.selectors import UniformFill

    monkeypatch.setitem(registry.ESTIMATORS, "fisher", lambda request: Estimate(torch.zeros(len(request.candidates))))
    session = CaptureSession.open(session_dir)
    with pytest.warns(UniformFill):
        proposal = session.propose(
            ProposalRequest(allow_empty=True, n=4, n_candidates=60, method="fisherrf-sampling", seed=3), map=False
        )
    assert len(proposal) == 4 and proposal.uniform_fill == 4
    assert session.proposals[-1].model_extra["uniform_fill"] == 4
    written = json.loads((session_dir / session.proposals[-1].file).read_text())
    assert written["nerfaug"]["uniform_fill"] == 4
    assert (
        "uniform_fill"
        not in CaptureSession.open(session_dir)
        .propose(ProposalRequest(allow_empty=True, n=4, n_candidates=60, selection=FAST, seed=3), map=False)
        .transforms()["nerfaug"]
    )

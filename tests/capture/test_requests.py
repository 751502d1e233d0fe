"""The capture core's schemas (`nerfaug.capture.requests`, `ProposalRequest`, `ViewConstraints`,
`SessionState`): each range refused with one line naming the field and the value, defaults filled
in, and session.json read and written through its model, including a file the earlier writer made
(tests/capture/data/session_v1.json)."""

import copy
import json
import math
from pathlib import Path

import pytest
import torch
from pydantic import TypeAdapter, ValidationError

from nerfaug.capture import Intrinsics, ProposalRequest, SessionSettings, SessionState, ViewConstraints
from nerfaug.capture.proposal_request import MAX_CANDIDATES, MAX_REACHABLE_POSES, MAX_VIEWS
from nerfaug.capture.requests import (
    RequestError,
    as_pose_list,
    as_poses,
    check_session_id,
    check_steps,
    check_threads,
    validated,
)
from nerfaug.capture.state import SessionError
from nerfaug.hemisphere import sample_uniform_poses
from nerfaug.nerf.engine import Engine
from nerfaug.selection import SelectionConfig

OLD_SESSION = Path(__file__).parent / "data" / "session_v1.json"
EYE = [[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


def refusal(make) -> RequestError:
    with pytest.raises(RequestError) as error:
        make()
    assert "\n" not in str(error.value)
    return error.value


@pytest.mark.parametrize(
    ("fields", "says"),
    [
        ({"seed": -1}, "seed -1: must be >= 0"),
        ({"seed": 2**53}, f"seed {2**53}: must be <= {2**53 - 1}"),  # JSON clients round larger ints
        ({"downscale": 0}, "downscale 0: must be >= 1"),
        ({"radius": 1e-300}, "radius 1e-300: must be >= 1e-06"),
        ({"radius": 1e7}, "radius 10000000.0: must be <= 1e+06"),
        ({"up": (0, 0, 0)}, "up (0, 0, 0): must be a non-zero direction"),
        ({"centre": (float("nan"), 0, 0)}, "centre[0] nan: Input should be a finite number"),
        ({"engine": "fastest"}, "engine 'fastest': unknown engine preset 'fastest'; choose one of: paper,"),
        ({"engine": "paper+hidden_dim=wide"}, "engine 'paper+hidden_dim=wide': hidden_dim='wide' is not a valid value"),
    ],
)
def test_session_settings_out_of_range_name_the_field_and_value(fields, says):
    assert str(refusal(lambda: SessionSettings(**fields).checked())).startswith(says)


def test_session_settings_defaults_and_conversions():
    settings = SessionSettings(centre=[1, 2, 3], radius=2).checked()
    assert settings == SessionSettings(centre=(1.0, 2.0, 3.0), radius=2.0)
    # No pole and no --estimate-up: the dataset's format decides (+z, or the cameras' up where it records none).
    assert (settings.engine.record(), settings.seed, settings.downscale) == ("nerfacto-cpu", 0, 1)
    assert (settings.up, settings.estimate_up) == (None, None)


@pytest.mark.parametrize(
    ("fields", "says"),
    [
        ({"n": 0}, "n 0: must be >= 1"),
        ({"n": MAX_VIEWS + 1}, f"n {MAX_VIEWS + 1}: must be <= {MAX_VIEWS}"),
        ({"n_candidates": 0}, "n_candidates 0: must be >= 1"),
        ({"n_candidates": MAX_CANDIDATES + 1}, f"n_candidates {MAX_CANDIDATES + 1}: must be <= {MAX_CANDIDATES}"),
        ({"min_separation": 180}, "min_separation 180: must be < 180"),
        ({"method": "best"}, "method 'best': unknown selection method 'best'; choose one of: ours,"),
        ({"seed": -2}, "seed -2: must be >= 0"),
        ({"selection": {"bogus": 1}}, "selection.bogus 1: unknown field"),
        ({"selection": {"sharpness": 2}}, "selection.sharpness 2: must be <= 1"),
        ({"selection": SelectionConfig(entropy_resolution=300)}, "selection.entropy_resolution 300: must be <= 256"),
        ({"constraints": {"elevation": [60, 10]}}, "constraints.elevation [60, 10]: low must be <= high"),
        ({"candidates": "reach.json"}, "candidates 'reach.json': Input should be a valid list"),
        ({"candidates": [EYE] * (MAX_REACHABLE_POSES + 1)}, "candidates ["),
        ({"unknown": 1}, "unknown 1: unknown field"),
    ],
)
def test_proposal_requests_out_of_range_name_the_field_and_value(fields, says):
    error = refusal(lambda: validated(ProposalRequest, fields))  # as the service reads a request's JSON
    assert str(error).startswith(says), str(error)[:200]


def test_a_selection_setting_beyond_what_one_proposal_may_ask_is_named():
    error = refusal(lambda: ProposalRequest(selection=SelectionConfig(entropy_resolution=300)).checked())
    assert (error.argument, error.value, error.problem) == ("selection.entropy_resolution", 300, "must be <= 256")


def test_a_request_checked_once_passes_the_layers_below_unchecked_again():
    request = ProposalRequest(selection=SelectionConfig(sharpness=0.5)).checked()
    assert request.checked() is request
    request.selection.sharpness = 3.0  # a change inside clears the mark
    assert str(refusal(request.checked)) == "selection.sharpness 3.0: must be <= 1"


def test_reachable_poses_are_a_file_only_from_python_never_from_json(tmp_path):
    assert ProposalRequest(candidates=tmp_path / "reach.json").checked().candidates == tmp_path / "reach.json"
    with pytest.raises(ValidationError, match="candidates"):  # what a client sends is JSON: a string is no file
        TypeAdapter(ProposalRequest).validate_json(json.dumps({"candidates": "/etc/passwd"}))
    poses = sample_uniform_poses(3, torch.Generator().manual_seed(0))
    checked = ProposalRequest(candidates=poses).checked().candidates
    assert torch.equal(torch.tensor(checked, dtype=torch.float32), poses)  # a tensor becomes the same numbers


def test_the_proposal_schema_states_its_bounds():
    schema = TypeAdapter(ProposalRequest).json_schema()["properties"]
    assert schema["n"]["maximum"] == MAX_VIEWS and schema["n_candidates"]["maximum"] == MAX_CANDIDATES
    assert schema["candidates"]["anyOf"][0]["maxItems"] == MAX_REACHABLE_POSES
    assert schema["min_separation"]["exclusiveMaximum"] == 180
    assert "proposal" in schema["seed"]["description"]  # each field's docstring is its description


@pytest.mark.parametrize(
    ("value", "says"),
    [
        ([[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, float("nan")], [0, 0, 0, 1]]], "poses[0] "),
        ([[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]], "poses[0] "),
        ([[[1, 0, 0], [0, 1, 0], [0, 0, 1]]], "poses[0] "),
        ([], "poses []: Value should have at least 1 item"),
    ],
)
def test_poses_are_checked_one_by_one(value, says):
    error = refusal(lambda: as_poses(value))
    assert str(error).startswith(says)
    assert error.problem in (
        "not finite (every entry of a pose must be a finite number)",
        "transform_matrix rotation is not rigid (R^T R != I or det(R) != 1)",
        "transform_matrix must be 4x4, has shape (3, 3)",
        "Value should have at least 1 item after validation, not 0",
    )


def test_one_pose_or_a_tensor_of_them_is_a_list_of_poses():
    assert as_pose_list(EYE) == [EYE]
    assert as_pose_list(torch.eye(4)[None].repeat(2, 1, 1)) == [EYE, EYE]


def test_intrinsics_defaults_follow_the_camera():
    k = Intrinsics(width=8, height=6, fx=10.0)
    assert (k.fy, k.cx, k.cy) == (10.0, 4.0, 3.0)
    assert k.camera_angle_x == pytest.approx(2 * math.atan(8 / 20))
    recorded = json.loads(OLD_SESSION.read_text())["intrinsics"]  # as `Cameras` computed it
    without_angle = {k: v for k, v in recorded.items() if k != "camera_angle_x"}
    assert Intrinsics(**without_angle).camera_angle_x == pytest.approx(recorded["camera_angle_x"], rel=1e-6)
    with pytest.raises(ValueError, match="fx"):
        Intrinsics(width=8, height=8, fx=-1)


def test_session_ids_and_steps_have_one_check_each():
    assert check_session_id("robot_1-a") == "robot_1-a"
    for bad in ("a.b", "-x", "", "x" * 65, "../evil"):
        assert str(refusal(lambda bad=bad: check_session_id(bad))).startswith(f"session id {bad!r}: must be 1-64")
    assert check_steps(0) == 0
    assert str(refusal(lambda: check_steps(-1))) == "steps -1: must be >= 0"


def test_constraints_are_one_class_for_the_library_the_cli_and_the_service():
    data = {"elevation": [10, 60], "azimuth": [-45, 405], "keep_out": [[0, 1, 0, 30]]}
    constraints = ViewConstraints.from_dict(data)
    assert constraints == ViewConstraints(elevation=(10, 60), azimuth=(-45, 405), keep_out=((0, 1, 0, 30),)).checked()
    assert ProposalRequest(constraints=data).checked().constraints == constraints


# ---- session.json ------------------------------------------------------------------------------


def as_format_2(old: dict) -> dict:
    """A format-1 session.json as format 2 writes it: the engine's name under "engine" (was
    "preset"), its settings under "engine_config" (was "engine"), in the same places."""
    renamed = {"preset": "engine", "engine": "engine_config"}
    return {renamed.get(k, k): v for k, v in old.items()} | {"format": 2}


def test_a_session_json_the_earlier_writer_made_reads_and_writes_back_with_the_engine_renamed():
    written = json.loads(OLD_SESSION.read_text())
    assert written["format"] == 1 and written["preset"] == "test"
    state = SessionState.from_dict(copy.deepcopy(written), OLD_SESSION)
    assert state.engine == "test" and state.engine_config == written["engine"]
    assert state.settings().engine == Engine.of("test")
    assert state.to_dict() == as_format_2(written)
    assert json.loads(json.dumps(state.to_dict())) == as_format_2(written)
    assert list(state.to_dict()) == list(as_format_2(written))  # the historic key order
    again = SessionState.from_dict(state.to_dict(), OLD_SESSION)  # format 2 reads back unchanged
    assert again.to_dict() == state.to_dict()
    # Its records keep the keys they hold beyond the typed ones.
    assert state.proposals[0].model_extra["min_separation"] == 5.0
    assert state.additions[1].warnings and "again" in state.additions[1].warnings[0]
    assert state.additions[0].warnings == []


def test_a_session_json_saved_before_digests_still_loads():
    older = json.loads(OLD_SESSION.read_text())
    for key in ("integrity", "saved"):
        del older[key]
    state = SessionState.from_dict(copy.deepcopy(older), OLD_SESSION)
    assert state.integrity.checkpoint is None and not state.integrity.captures
    assert state.to_dict() == as_format_2(older)  # no integrity section until there is something in it


def test_the_settings_a_session_was_made_with():
    state = SessionState.from_dict(json.loads(OLD_SESSION.read_text()), OLD_SESSION)
    ours = state.settings()
    assert ours == SessionSettings(
        engine=Engine.of("test"), seed=7, radius=4.03, centre=None, up=(0.0, 0.0, 1.0), estimate_up=False
    )
    asked = SessionSettings(engine="cpu", seed=7, centre=(0, 0, 0), radius=None, estimate_up=True)
    assert asked.differences(ours, {"engine", "seed", "centre", "radius", "up", "estimate_up"}) == [
        ("engine", "cpu", "test"),
        ("centre", "0 0 0", "estimated"),
        ("radius", "not given, so estimated", "4.03"),
        ("estimate_up", "on", "off"),
    ]
    assert asked.differences(ours, {"seed"}) == []


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda d: d.update(format=3), "field 'format': unsupported session format"),
        (lambda d: d.update(downscale=300), "field 'downscale': must be <= 256"),  # SessionSettings' bounds
        (lambda d: d.update(step="many"), "field 'step'"),
        (lambda d: d["intrinsics"].update(width=0), "field 'intrinsics.width': must be >= 1"),
        (lambda d: d["dataset"].update(json="../x.json"), "field 'dataset.json': must be a path inside the run"),
        (lambda d: d["proposals"][0].pop("names"), "field 'proposals[0].names': Field required (got None)"),
        (lambda d: d["hemisphere"].update(up=[0, 0, 0]), "field 'hemisphere': not a valid hemisphere"),
    ],
)
def test_a_damaged_session_json_is_one_line_naming_the_file_and_field(change, field):
    data = json.loads(OLD_SESSION.read_text())
    change(data)
    with pytest.raises(SessionError) as error:
        SessionState.from_dict(data, OLD_SESSION)
    assert str(error.value).startswith(f"{OLD_SESSION}, {field}")
    assert "\n" not in str(error.value) and "restore it" in str(error.value)


def test_a_thread_count_below_one_is_refused_by_the_library():
    assert check_threads(2) == 2
    with pytest.raises(RequestError, match=r"^threads 0: must be >= 1$"):
        check_threads(0)


def test_proposal_seeds_stay_within_what_a_json_client_reads_exactly():
    from nerfaug.capture.proposal import proposal_seed
    from nerfaug.capture.requests import SEED_MAX

    assert SEED_MAX == 2**53 - 1
    seeds = [proposal_seed(seed, number) for seed in (0, 1, SEED_MAX) for number in range(200)]
    assert max(seeds) <= SEED_MAX and max(seeds) > 2**50  # the whole range is used
    assert all(float(s) == s for s in seeds)  # a float64 (a JavaScript number) holds each exactly
    assert len(set(seeds)) == len(seeds)

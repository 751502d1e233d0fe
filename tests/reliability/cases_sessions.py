"""Bad inputs and clashes of capture sessions left to run: seeds beyond 64 bits, radii out of range,
datasets that fail half-way through a new session, proposals written over files nerfaug did not
write or over a session's own records, a checkpoint that cannot be checked by its digest, and a
session another process is changing."""

from __future__ import annotations

import json
import os
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from cases import case, copy_dataset, edit_json, train_on
from cases_capture import _propose, _propose_case, _session
from harness import Case, run_cli

BEYOND = str(2**64)
_HELD: list = []  # lock files held by this process for a case (released when it ends)


@case
def train_seed_beyond_64_bits(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--seed", BEYOND).argv, [data, tmp], says=("--seed", BEYOND))


@case
def propose_seed_beyond_64_bits(tmp, bases):
    return _propose_case(tmp, bases, "--seed", BEYOND, says=("--seed", BEYOND))


@case
def train_radius_far_too_small(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--radius", "1e-300").argv, [data, tmp], says=("--radius", "1e-300"))


@case
def train_radius_far_from_the_cameras(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--radius", "100000").argv, [data, tmp], says=("radius", "100000"))


def _one_image_changed(tmp, bases, change) -> Case:
    data = copy_dataset(tmp, bases)
    image = sorted((data / "train").glob("*.png"))[3]
    change(image)
    return Case(train_on(data, tmp, "--split", "train").argv, [data, tmp], says=(image.stem,))


@case
def train_dataset_with_one_image_of_another_size(tmp, bases):
    """A new session that fails on one image leaves no half-made run folder behind."""
    bigger = np.zeros((16, 16, 3), dtype=np.uint8)
    return _one_image_changed(tmp, bases, lambda image: iio.imwrite(image, bigger))


@case
def train_dataset_with_a_truncated_image(tmp, bases):
    return _one_image_changed(tmp, bases, lambda image: image.write_bytes(image.read_bytes()[:40]))


@case
def propose_over_a_users_image_beside_its_poses_file(tmp, bases):
    """`poses.json` is nerfaug's (an earlier proposal), `poses.png` beside it is the user's own image."""
    run = _session(tmp, bases)
    first = run_cli(_propose(run, tmp))
    assert first.code == 0, first.err
    (tmp / "poses.png").write_bytes(b"\x89PNG my own picture")
    return Case(_propose(run, tmp), [run, tmp / "poses.json", tmp / "poses.png"], says=("poses.png",))


def _over_a_record(tmp, bases, *extra) -> Case:
    run = _session(tmp, bases)
    first = run_cli(_propose(run, tmp))
    assert first.code == 0, first.err
    record = run / "proposals" / "proposal_000.json"
    argv = ["propose", run, "--out", record, "--n-candidates", "12", "--device", "cpu", *extra]
    return Case(argv, [run, tmp / "poses.json"], says=("proposal_000.json", "capture session"))


@case
def propose_out_is_a_sessions_own_record(tmp, bases):
    return _over_a_record(tmp, bases)


@case
def propose_out_is_a_sessions_own_record_forced(tmp, bases):
    return _over_a_record(tmp, bases, "--force")


@case
def checkpoint_copied_into_a_session_saved_before_digests(tmp, bases):
    """A session an earlier nerfaug saved (no digests in session.json) with another session's checkpoint."""
    run = _session(tmp, bases)
    other = tmp / "other"
    argv = ["train", bases.dataset, "--out", other, "--engine", "test", "--steps", "2", "--seed", "1"]
    outcome = run_cli([*argv, "--device", "cpu"])
    assert outcome.code == 0, outcome.err
    edit_json(run / "session.json", lambda data: data.pop("integrity", None))
    (run / "checkpoint.pt").write_bytes((other / "checkpoint.pt").read_bytes())
    # --steps is the step to reach: beyond the session's 3, so the checkpoint is loaded.
    return Case(["train", run, "--steps", "10", "--device", "cpu"], [run], says=("checkpoint.pt", "another session"))


def _hold(run: Path, holder: str) -> None:
    """Take the session's lock file from this process as `holder` would (kept until the process ends)."""
    import fcntl

    handle = open(run / ".lock", "a+")  # noqa: SIM115 -- held past this function on purpose
    fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    handle.truncate(0)
    handle.write(json.dumps({"pid": os.getpid(), "holder": holder, "since": "2026-11-25T10:00:00+00:00"}))
    handle.flush()
    _HELD.append(handle)


@case
def train_a_session_a_service_holds(tmp, bases):
    run = _session(tmp, bases)
    _hold(run, "nerfaug serve")
    argv = ["train", run, "--steps", "10", "--device", "cpu"]  # beyond the session's step 3
    return Case(argv, [run], code=1, says=(str(run), "`nerfaug serve`", str(os.getpid())))


@case
def add_to_a_session_a_service_holds(tmp, bases):
    run = _session(tmp, bases)
    _hold(run, "nerfaug serve")
    (tmp / "none").mkdir()
    argv = ["add", run, "--images", tmp / "none", "--poses", tmp / "none.json", "--device", "cpu"]
    return Case(argv, [run], code=1, says=(str(run), "`nerfaug serve`"))

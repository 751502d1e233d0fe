import json
import shutil
import subprocess

import pytest

from nerfaug.experiment.config import PROTOCOL_PRESETS, ExperimentConfig
from nerfaug.experiment.store import (
    IncompatibleResults,
    RunKey,
    check_sweep,
    clear_incomplete,
    dataset_content_digest,
    fingerprint,
    read_result,
    write_result,
)
from nerfaug.experiment.sweep import finished_in_plan, plan_runs, sweep_record


def complete_result(fp="abc", psnr=20.0):
    return {
        "scene": "lego",
        "method": "ours",
        "trial": 0,
        "seed": 0,
        "fingerprint": fp,
        "metrics": {"psnr": psnr, "ssim": 0.8, "lpips": None},
        "timing": {"total": 1.0},
        "code_version": "test",
    }


def test_result_round_trip_and_fingerprint_check(tmp_path):
    folder = RunKey("lego", "ours", 0).folder(tmp_path)
    write_result(folder, complete_result())
    assert read_result(folder, "abc")["metrics"]["psnr"] == 20.0
    assert read_result(folder, "other") is None  # made with another configuration


@pytest.mark.parametrize(
    "content",
    [
        '{"scene": "lego", "metr',
        "[]",
        json.dumps({"scene": "lego"}),
        json.dumps({**complete_result(), "metrics": {"psnr": "NaN?"}}),
    ],
)
def test_partial_or_corrupted_results_are_not_complete(tmp_path, content):
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "result.json").write_text(content)
    assert read_result(folder, "abc") is None
    assert clear_incomplete(folder) and not folder.exists()


def test_write_result_refuses_incomplete_records(tmp_path):
    with pytest.raises(ValueError, match="missing"):
        write_result(tmp_path, {"scene": "lego"})


def test_incompatible_sweep_is_refused_with_the_changed_settings(tmp_path):
    first = sweep_record(PROTOCOL_PRESETS.choose("tiny"), ["nerfaug"])
    check_sweep(tmp_path, first)
    check_sweep(tmp_path, first)  # same config: fine
    grown = sweep_record(PROTOCOL_PRESETS.choose("tiny", trials=5, methods=("ours", "uniform", "entropy")), ["nerfaug"])
    check_sweep(tmp_path, grown)  # more trials or methods do not change any run's numbers
    changed = sweep_record(PROTOCOL_PRESETS.choose("tiny").replace(steps=999), ["nerfaug"])
    with pytest.raises(IncompatibleResults, match=r"steps: 60 -> 999.*--force"):
        check_sweep(tmp_path, changed)
    finished = RunKey("lego", "ours", 0).folder(tmp_path)
    write_result(finished, complete_result(first["fingerprint"]))
    moved = check_sweep(tmp_path, changed, force=True)
    assert not (tmp_path / "runs").exists()
    # --force moves finished results aside; it deletes nothing.
    assert read_result(moved / finished.relative_to(tmp_path), first["fingerprint"]) is not None
    assert json.loads((tmp_path / "sweep.json").read_text())["fingerprint"] == changed["fingerprint"]


def test_a_resume_counts_only_its_own_finished_runs(tmp_path):
    # A study's engine folder holds every scene's runs: the size line of a study of one scene counted
    # all of them ("80 already finished, 0 to run" while 29 were left).
    config = PROTOCOL_PRESETS.choose("tiny").replace(scenes=("lego",), trials=2)  # 2 methods x 2 trials
    for key in [RunKey("lego", "ours", 0), RunKey("chair", "ours", 0), RunKey("chair", "uniform", 1)]:
        write_result(key.folder(tmp_path), {**complete_result(), "scene": key.scene, "method": key.method})
    RunKey("lego", "ours", 5).folder(tmp_path).mkdir(parents=True)  # a trial beyond the plan's
    write_result(RunKey("lego", "uniform", 7).folder(tmp_path), complete_result())
    assert finished_in_plan(config, tmp_path) == 1
    # Runs a study's table records are not run again either.
    assert (
        finished_in_plan(config, tmp_path, {RunKey("lego", "uniform", 1): "fp", RunKey("chair", "ours", 1): "fp"}) == 2
    )
    assert finished_in_plan(config, tmp_path / "nothing here") == 0


def test_fingerprint_is_stable_and_sensitive():
    config = ExperimentConfig()
    assert fingerprint(config.fingerprinted()) == fingerprint(ExperimentConfig().fingerprinted())
    assert fingerprint(config.fingerprinted()) != fingerprint(config.replace(seed=1).fingerprinted())


def test_plan_covers_every_cell():
    config = PROTOCOL_PRESETS.choose("tiny").replace(scenes=("lego", "chair"), trials=3)
    keys = plan_runs(config)
    assert len(keys) == 2 * 2 * 3 and len(set(keys)) == len(keys)
    assert RunKey("chair", "uniform", 2) in keys
    # Trial by trial: every method's trial 0 before any method's trial 1.
    assert keys[:4] == [
        RunKey("lego", "ours", 0),
        RunKey("lego", "uniform", 0),
        RunKey("lego", "ours", 1),
        RunKey("lego", "uniform", 1),
    ]


def test_dataset_content_digest_covers_the_images_runs_read_and_nothing_else(tmp_path):
    import torch

    from nerfaug.cameras import Cameras
    from nerfaug.data import Views, write_blender_split

    poses = torch.eye(4).repeat(2, 1, 1)
    poses[:, 2, 3] = torch.tensor([3.0, 4.0])
    images = torch.rand(2, 4, 4, 3, generator=torch.Generator().manual_seed(0))
    views = Views(Cameras.from_fov(poses, 0.7, 4, 4), images, ["./a", "./b"])
    for split in ("train", "test"):
        write_blender_split(tmp_path, split, views)
    digest = dataset_content_digest(tmp_path, ("train", "test"))
    (tmp_path / "notes.txt").write_text("not read by any run")
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "sweep.json").write_text("{}")
    assert dataset_content_digest(tmp_path, ("train", "test")) == digest
    image = next((tmp_path / "test").glob("*.png"))
    image.write_bytes(image.read_bytes() + b"\0")  # same cameras, other image bytes
    assert dataset_content_digest(tmp_path, ("train", "test")) != digest


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_checkout_version_calls_the_code_dirty_only_when_the_package_changed(tmp_path):
    """A changed results table beside the package leaves the version clean; a changed or new
    file in the package makes it "-dirty"; a folder outside any checkout has no version."""
    from nerfaug.experiment.store import checkout_version

    def git(*args):
        done = subprocess.run(["git", "-C", str(tmp_path), *args], check=True, capture_output=True, text=True)
        return done.stdout.strip()

    package, table = tmp_path / "src" / "pkg", tmp_path / "docs" / "table.json"
    package.mkdir(parents=True)
    table.parent.mkdir()
    (package / "code.py").write_text("x = 1\n")
    table.write_text("{}\n")
    git("init", "-q")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "first")
    commit = git("rev-parse", "--short=12", "HEAD")
    assert checkout_version(package) == commit
    table.write_text('{"runs": []}\n')  # what a study sitting changes
    assert checkout_version(package) == commit
    (package / "new.py").write_text("y = 2\n")  # untracked code counts
    assert checkout_version(package) == f"{commit}-dirty"
    (package / "new.py").unlink()
    (package / "code.py").write_text("x = 2\n")
    assert checkout_version(package) == f"{commit}-dirty"
    outside = tmp_path.parent / f"{tmp_path.name}-outside"
    outside.mkdir()
    in_a_checkout = subprocess.run(["git", "-C", str(outside), "rev-parse"], capture_output=True).returncode == 0
    if not in_a_checkout:  # the temporary folders of an ordinary machine
        assert checkout_version(outside) is None

"""Run folders of one scene that disagree (other test views or other initial views: runs of two
versions of a dataset in one study folder) given to `nerfaug study --summary-only`: one line naming
the run folder and the table, exit 2 (input the table cannot hold), and nothing written: the table
as it was (or still absent), every run folder byte for byte as it was."""

import json
import shutil
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import Views, write_blender_split
from nerfaug.hemisphere import (
    BLENDER_CAMERA_ANGLE_X,
    fibonacci_angles,
    half_hemisphere_poses,
    pose_from_angles,
    sample_uniform_poses,
)

SIZE = 16
TAMPERED = Path("test", "runs", "scene", "uniform", "trial_001")


def views(poses, prefix: str) -> Views:
    """Views of a smooth colour ramp: training needs images, not a particular scene."""
    cameras = Cameras.from_fov(poses.float(), BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
    ramp = torch.linspace(0, 1, SIZE)
    image = torch.stack(
        [ramp[:, None].expand(SIZE, SIZE), ramp[None, :].expand(SIZE, SIZE), 0.5 * torch.ones(SIZE, SIZE)], -1
    )
    images = (image.expand(len(cameras), SIZE, SIZE, 3) * 255).round() / 255
    return Views(cameras, images, [f"./{prefix}/r_{i}" for i in range(len(cameras))])


@pytest.fixture(scope="module")
def study_out(tmp_path_factory) -> Path:
    """A finished toy study: the test engine, uniform, 2 trials of one scene, and its table."""
    from nerfaug.cli import main

    root = tmp_path_factory.mktemp("data") / "scene"
    write_blender_split(root, "train", views(sample_uniform_poses(8, torch.Generator().manual_seed(0)), "train"))
    write_blender_split(root, "initial", views(half_hemisphere_poses(3), "initial"))
    write_blender_split(root, "test", views(pose_from_angles(*fibonacci_angles(3)), "test"))
    out = tmp_path_factory.mktemp("study")
    main(
        ["study", "--out", str(out), "--preset", "tiny", "--engines", "test", "--scenes", str(root)]
        + ["--methods", "uniform", "--trials", "2", "--resolution", str(SIZE), "--steps", "30"]
        + ["--workers", "1", "--device", "cpu"]
    )  # fmt: skip
    assert (out / TAMPERED / "result.json").is_file() and (out / "study-table.json").is_file()
    return out


def tamper(folder: Path, what: str) -> None:
    """The second run as if made from another version of the dataset."""
    if what == "test views":
        path = folder / "result.json"
        result = json.loads(path.read_text())
        result["views"]["test"] = result["views"]["test"][:-1]
    else:
        path = folder / "selection.json"
        result = json.loads(path.read_text())
        result["train_poses"][0][0][3] += 0.5
    path.write_text(json.dumps(result))


def files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("what", ["test views", "initial views"])
@pytest.mark.parametrize("table", ["--table FILE", "--table not yet written", "OUT's own table"])
def test_runs_that_disagree_are_one_line_exit_2_and_nothing_is_written(study_out, what, table, tmp_path, capsys):
    from nerfaug.cli import main

    out = tmp_path / "study"
    shutil.copytree(study_out, out)
    tamper(out / TAMPERED, what)
    path = out / "study-table.json"
    argv = ["study", "--summary-only", "--out", str(out)]
    if table != "OUT's own table":
        path = tmp_path / "tables" / "study-table.json"
        argv += ["--table", str(path)]
        if table == "--table FILE":
            path.parent.mkdir()
            shutil.copy(study_out / "study-table.json", path)
    before = files(tmp_path)
    with pytest.raises(SystemExit) as done:
        main(argv)
    err = capsys.readouterr().err
    assert done.value.code == 2, err
    assert err.startswith(f"nerfaug: {out / TAMPERED}: its {what} differ from other runs of scene 'scene'; "), err
    assert f"the table {path} was not written, and the runs are kept" in err and "another --out" in err, err
    assert err.count("\n") == 1 and "internal error" not in err, err
    assert files(tmp_path) == before  # the table as it was (or absent), the run folders untouched
    assert path.is_file() == (table != "--table not yet written")

"""Run folders of one scene that disagree with each other or with the table's record of the scene
(other test views or other initial views: runs of two versions of a dataset) given to `nerfaug study
--summary-only`: one line naming the run folder or the scene and the table, exit 2 (input the table
cannot hold), and nothing written: the table as it was (or still absent), every run folder byte for
byte as it was."""

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


def tamper_table(table: dict, what: str) -> dict:
    """The table as if its runs were made from another version of the dataset than OUT's."""
    scene = table["scenes"]["scene"]
    if what == "test views":
        scene["test_views"] = scene["test_views"][:-1]
        return table
    scene["initial_poses"][0][0][3] += 0.5
    return table


def summarise(out: Path, path: Path, capsys) -> tuple[int, str]:
    from nerfaug.cli import main

    try:
        main(["study", "--summary-only", "--out", str(out), "--table", str(path)])
    except SystemExit as done:
        return done.code, capsys.readouterr().err
    return 0, capsys.readouterr().err


@pytest.mark.parametrize("what", ["test views", "initial views"])
def test_runs_that_disagree_with_the_tables_scene_are_one_line_exit_2(study_out, what, tmp_path, capsys):
    out = tmp_path / "study"
    shutil.copytree(study_out, out)
    path = tmp_path / "tables" / "study-table.json"
    path.parent.mkdir()
    table = tamper_table(json.loads((study_out / "study-table.json").read_text()), what)
    path.write_text(json.dumps(table))
    before = files(tmp_path)
    code, err = summarise(out, path, capsys)
    field = "test_views" if what == "test views" else "initial_poses"
    assert code == 2, err
    assert err.startswith(
        f"nerfaug: scene 'scene': the runs' {what} differ from those the table records "
        f"({path}: scenes.scene.{field}); the table {path} was not written, and the runs are kept"
    ), err
    assert "another --out" in err and err.count("\n") == 1 and "internal error" not in err, err
    assert files(tmp_path) == before  # the table byte for byte as it was, the run folders untouched


def test_a_layout_the_table_has_not_seen_and_poses_within_its_rounding_are_accepted(study_out, tmp_path, capsys):
    """The table knows the scene only from runs of another layout (its layout 0 unrecorded), and
    records the test views with a pose a unit of the last decimal away: both agree with the runs."""
    out = tmp_path / "study"
    shutil.copytree(study_out, out)
    table = json.loads((study_out / "study-table.json").read_text())
    ours = table["scenes"]["scene"].pop("initial_poses")
    theirs = json.loads(json.dumps(ours))
    theirs[0][0][3] += 0.5
    table["scenes"]["scene"]["layouts"] = {"1": theirs}
    for run in table["runs"]:
        run["layout"] = 1
    path = tmp_path / "study-table.json"
    path.write_text(json.dumps(table))
    code, err = summarise(out, path, capsys)
    assert code == 0, err
    written = json.loads(path.read_text())["scenes"]["scene"]
    assert written["initial_poses"] == ours and written["layouts"] == {"1": theirs}

    nudged = json.loads(path.read_text())
    nudged["scenes"]["scene"]["initial_poses"][0][0][3] += 1e-6
    path.write_text(json.dumps(nudged))
    code, err = summarise(out, path, capsys)
    assert code == 0, err


def test_halves_are_compared_per_layout_and_fields_an_older_table_lacks_are_not():
    from nerfaug.report.study_table import RunsDisagree, check_against_table

    poses = [[[1.0, 0.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 2.0]]]
    half = {"start_deg": 0.0, "width_deg": 180.0}
    runs = {"mic": {"initial_poses": poses, "halves": {"0": half}, "test_views": ["r_0", "r_1"]}}
    older = {"scenes": {"mic": {"initial_poses": poses}}}  # no halves, no test views recorded
    check_against_table(runs, older, Path("t.json"))
    other_layout = {"scenes": {"mic": {"layouts": {"1": poses}, "halves": {"1": {**half, "start_deg": 90.0}}}}}
    check_against_table(runs, other_layout, Path("t.json"))
    turned = {"scenes": {"mic": {"initial_poses": poses, "halves": {"0": {**half, "start_deg": 90.0}}}}}
    field = r"\(t\.json: scenes\.mic\.halves\.0\)$"
    with pytest.raises(RunsDisagree, match=r"^scene 'mic': the runs' initial half differs from those .*" + field):
        check_against_table(runs, turned, Path("t.json"))


def study_again(study_out: Path, out: Path, table: Path) -> list[str]:
    """`nerfaug study` with the toy study's settings, into `out`, resuming from `table`."""
    dataset = json.loads((study_out / "study-table.json").read_text())["plan"]["datasets"]["scene"]
    return (
        ["study", "--out", str(out), "--table", str(table), "--preset", "tiny", "--engines", "test"]
        + ["--scenes", dataset, "--methods", "uniform", "--trials", "2", "--resolution", str(SIZE)]
        + ["--steps", "30", "--workers", "1", "--device", "cpu"]
    )  # fmt: skip


@pytest.mark.parametrize("what", ["test views", "initial views"])
def test_a_study_whose_scene_differs_from_its_tables_is_refused_before_any_run(study_out, what, tmp_path, capsys):
    """The dataset as it is on disk would give the runs other views than the table records for the
    scene: one line, exit 2, before anything runs or is written."""
    from nerfaug.cli import main

    path = tmp_path / "tables" / "study-table.json"
    path.parent.mkdir()
    path.write_text(json.dumps(tamper_table(json.loads((study_out / "study-table.json").read_text()), what)))
    out = tmp_path / "again"
    before = files(tmp_path)
    with pytest.raises(SystemExit) as done:
        main(study_again(study_out, out, path))
    err = capsys.readouterr().err
    field = "test_views" if what == "test views" else "initial_poses"
    assert done.value.code == 2, err
    assert err.startswith(
        f"nerfaug: scene 'scene': the runs' {what} differ from those the table records ({path}: scenes.scene.{field}), "
        "before any run"
    ), err
    assert "another --out" in err and err.count("\n") == 1 and "internal error" not in err, err
    assert files(tmp_path) == before and not out.exists()


def test_a_study_resumed_from_its_own_table_is_not_refused(study_out, tmp_path, capsys):
    """The same dataset and settings: every view agrees with the table, and every run it records is kept."""
    from nerfaug.cli import main

    path = tmp_path / "study-table.json"
    shutil.copy(study_out / "study-table.json", path)
    main(study_again(study_out, tmp_path / "again", path))
    err = capsys.readouterr().err
    assert "before any run" not in err, err
    assert json.loads(path.read_text())["runs"] == json.loads((study_out / "study-table.json").read_text())["runs"]

"""A capture of one view is refused, or warned about, in one line naming its file and the fix, by
every command that reads a capture: `train` (with and without `--initial`), `run --data` and
`scene prepare`; `estimate_centre` says the fix too (the service answers with it)."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from nerfaug.cli import main
from nerfaug.data.world_frame import TooFewCameras, estimate_centre

SIZE = 16


def one_view(root: Path) -> Path:
    """A nerfstudio folder of one image, its camera 4 units from the origin looking at it."""
    root.mkdir(parents=True)
    pixels = np.random.default_rng(0).integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(root / "a.png")
    pose = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]]
    listing = {"fl_x": 20.0, "fl_y": 20.0, "cx": 8.0, "cy": 8.0, "w": SIZE, "h": SIZE}
    frames = [{"file_path": "a.png", "transform_matrix": pose}]
    (root / "transforms.json").write_text(json.dumps({**listing, "frames": frames}))
    return root


def refusal(capsys, argv) -> str:
    with pytest.raises(SystemExit) as ended:
        main(argv)
    assert ended.value.code != 0
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize("extra", [(), ("--initial", "1")])
def test_train_names_the_listing_and_the_fix(tmp_path, capsys, extra):
    data = one_view(tmp_path / "data")
    argv = ["train", str(data), "--out", str(tmp_path / "run"), "--engine", "test", "--steps", "1", *extra]
    line = refusal(capsys, [*argv, "--device", "cpu"])
    assert line.startswith(f"nerfaug: {data / 'transforms.json'}: 1 view, "), line
    assert line.endswith("capture at least 2 views, or give --centre X Y Z and --radius R"), line
    assert not (tmp_path / "run").exists()  # the refused session leaves nothing


def test_train_goes_on_with_the_centre_and_radius_given(tmp_path, capsys):
    """The fix the refusal names works: a centre and radius given need no second camera."""
    data = one_view(tmp_path / "data")
    argv = ["train", str(data), "--out", str(tmp_path / "run"), "--engine", "test", "--steps", "1"]
    main([*argv, "--device", "cpu", "--centre", "0", "0", "0", "--radius", "4"])
    assert (tmp_path / "run" / "session.json").is_file()


def test_run_names_the_listing_and_the_views_it_needs(tmp_path, capsys):
    data = one_view(tmp_path / "data")
    argv = ["run", "--data", str(data), "--out", str(tmp_path / "out"), "--engine", "test", "--resolution", "16"]
    line = refusal(capsys, argv)
    assert line.startswith(f"nerfaug: {data / 'transforms.json'}: a captured set of 1 view is too small"), line
    assert "capture at least 4 views" in line, line


def test_scene_prepare_warns_in_one_line_naming_the_source(tmp_path, capsys):
    """Prepared all the same (a training with the centre given can use it), with the fix said."""
    data = one_view(tmp_path / "data")
    main(["scene", "prepare", str(data), "--out", str(tmp_path / "prepared"), "--width", "8"])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning")]
    assert len(lines) == 1 and lines[0].startswith(f"warning: {data}: 1 view; "), lines
    assert lines[0].endswith("capture more views"), lines
    assert (tmp_path / "prepared" / "transforms.json").is_file()


def test_a_capture_of_four_views_is_prepared_without_a_warning(tmp_path, capsys):
    data = one_view(tmp_path / "data")
    listing = json.loads((data / "transforms.json").read_text())
    frame = listing["frames"][0]
    listing["frames"] = [{**frame, "transform_matrix": _around(k)} for k in range(4)]
    (data / "transforms.json").write_text(json.dumps(listing))
    main(["scene", "prepare", str(data), "--out", str(tmp_path / "prepared"), "--width", "8"])
    assert "warning" not in capsys.readouterr().err


def _around(k: int) -> list:
    """A camera 4 units from the origin at azimuth k * 90 degrees, looking at it (OpenGL, -z forward)."""
    angle = k * np.pi / 2
    back = np.array([np.sin(angle), 0.0, np.cos(angle)])  # the camera's +z, away from the origin
    pose = np.eye(4)
    up = np.array([0.0, 1.0, 0.0])
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = np.cross(up, back), up, back, 4 * back
    return pose.tolist()


def test_estimate_centre_names_the_count_and_the_fix():
    with pytest.raises(TooFewCameras, match="needs at least 2 cameras, got 1: capture at least 2 views") as refused:
        estimate_centre(torch.eye(4)[None])
    assert refused.value.count == 1 and isinstance(refused.value, ValueError)

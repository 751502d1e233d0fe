"""A dataset format defined outside the package and registered with one line works everywhere a
dataset is read or grown: `load_dataset`, an experiment (a sweep) and a capture session (create, add,
export, reopen). The toy format stores its listing under keys of its own, so every operation
goes through the `Format` interface, not through the layout of the built-in formats."""

from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession, SessionSettings
from nerfaug.data import FORMATS, Format, Views, get_format, load_dataset, register_format
from nerfaug.data.frames import load_frames, write_image
from nerfaug.hemisphere import half_hemisphere_poses, pose_from_angles

SIZE = 12


class ToyFormat(Format):
    """`toy_{split}.json`: {"focal", "principal": [cx, cy], "views": [{"image", "pose"}]}, images
    in `pictures_{split}/`. One focal length and principal point for every view, anywhere."""

    name = "toy"
    fits_rule = "one focal length and principal point"
    camera_keys = ("focal", "principal")

    def listing(self, root: Path, split: str) -> Path:
        return Path(root) / f"toy_{split}.json"

    def image_folder(self, split: str) -> str:
        return f"pictures_{split}"

    def file_path(self, folder: str, stem: str, suffix: str) -> str:
        return f"{folder}/{stem}{suffix}"

    def read_listing(self, root: Path, split: str) -> tuple[dict, list]:
        import json

        data = json.loads(self.listing(root, split).read_text())
        frames = [{"file_path": v["image"], "transform_matrix": v["pose"]} for v in data.pop("views")]
        return data, frames

    def write_listing(self, root: Path, split: str, header: dict, frames: list) -> Path:
        import json

        views = [{"image": f["file_path"], "pose": f["transform_matrix"]} for f in frames]
        path = self.listing(root, split)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({**header, "views": views}))
        return path

    def load(self, root, split="train", background=(1.0, 1.0, 1.0), downscale=1, lazy=False) -> Views:
        header, frames = self.read_listing(Path(root), split)
        focal, (cx, cy) = header["focal"], header["principal"]
        listing = self.listing(Path(root), split)
        return load_frames(
            Path(root), listing, frames, background, downscale, lazy, lambda w, h, i: (None, (focal, focal, cx, cy))
        )

    def fits(self, cameras: Cameras) -> bool:
        return all(bool((v - v[0]).abs().max() <= 1e-4 * v[0].abs()) for v in (cameras.fx, cameras.fy, cameras.cx))

    def describe(self, cameras: Cameras) -> tuple[dict, list[dict]]:
        header = {"focal": float(cameras.fx[0]), "principal": [float(cameras.cx[0]), float(cameras.cy[0])]}
        return header, [{} for _ in range(len(cameras))]

    def write(self, root, split, views, background=(1.0, 1.0, 1.0)) -> Path:
        folder, frames = self.image_folder(split), []
        for i, pose in enumerate(views.cameras.camera_to_world):
            write_image(Path(root) / folder / f"v{i}.png", views.images[i])
            frames.append({"file_path": f"{folder}/v{i}.png", "transform_matrix": pose.tolist()})
        return self.write_listing(Path(root), split, self.describe(views.cameras)[0], frames)


@pytest.fixture
def toy():
    with register_format(ToyFormat()) as fmt:  # the one line that adds the format
        yield fmt


def toy_views(poses: torch.Tensor, size: int = SIZE) -> Views:
    """Views of a camera whose principal point is off the centre (no Blender camera_angle_x)."""
    n = len(poses)
    focal = torch.full((n,), 14.0 * size / SIZE)
    cx, cy = torch.full((n,), 5.0 * size / SIZE), torch.full((n,), 7.0 * size / SIZE)
    cameras = Cameras(poses, focal, focal, cx, cy, size, size)
    images = torch.rand(n, size, size, 3, generator=torch.Generator().manual_seed(n))
    return Views(cameras, (images * 255).round() / 255, [f"v{i}" for i in range(n)])


def test_a_registered_format_is_read_as_views(toy, tmp_path):
    views = toy_views(half_hemisphere_poses(4, radius=2.0))
    toy.write(tmp_path, "train", views)
    loaded = load_dataset(tmp_path, "train")
    assert torch.equal(loaded.images, views.images)
    assert torch.allclose(loaded.cameras.camera_to_world, views.cameras.camera_to_world, atol=1e-6)
    assert loaded.cameras.cx.tolist() == [5.0] * 4 and get_format("toy") is toy


def test_a_session_grows_and_exports_a_dataset_in_a_registered_format(toy, tmp_path):
    data = tmp_path / "data"
    toy.write(data, "train", toy_views(half_hemisphere_poses(5, radius=2.0)))
    toy.write(data, "test", toy_views(half_hemisphere_poses(2, radius=2.0, azimuth_start=1.0)))
    session = CaptureSession.create(data, tmp_path / "run", SessionSettings(engine="test", seed=1))
    assert session.state.dataset.format == "toy"  # Blender cannot hold its camera: kept as it is
    assert (session.dataset_dir / "toy_train.json").is_file()

    pose = pose_from_angles(torch.tensor([2.5]), torch.tensor([0.6]), radius=2.0)
    capture = (torch.rand(1, SIZE, SIZE, 3) * 255).round() / 255
    assert session.add_views(capture, pose, names=["new"]) == ["new"]
    session.save()
    reopened = CaptureSession.open(tmp_path / "run")
    assert len(reopened.trainer.train_views) == 6
    grown = load_dataset(session.dataset_dir)
    assert grown.names[-1] == "pictures_train/new.png" and torch.equal(grown.images[-1], capture[0])

    listing = session.export(tmp_path / "out", "toy")
    exported = load_dataset(listing.parent)
    assert torch.equal(exported.images, grown.images) and exported.cameras.cy.tolist() == [7.0] * 6
    assert len(load_dataset(listing.parent, "test")) == 2  # the source's held-out split came along
    assert len(load_dataset(session.export(tmp_path / "ns", "nerfstudio").parent)) == 6
    with pytest.raises(ValueError, match="export with format='nerfstudio' or 'idr' or 'toy'"):
        session.export(tmp_path / "bl", "blender")


def test_an_experiment_runs_on_a_dataset_in_a_registered_format(toy, tmp_path):
    from nerfaug.experiment.config import PROTOCOL_PRESETS
    from nerfaug.experiment.store import RunKey
    from nerfaug.experiment.sweep import run_sweep
    from nerfaug.hemisphere import sample_uniform_poses

    config = PROTOCOL_PRESETS.choose("tiny").replace(methods=("ours",), trials=1)
    data = tmp_path / "data"
    poses = sample_uniform_poses(config.pool, torch.Generator().manual_seed(0))
    toy.write(data, "train", toy_views(poses, config.resolution))
    toy.write(data, "initial", toy_views(half_hemisphere_poses(config.n_initial), config.resolution))
    toy.write(data, "test", toy_views(poses[: config.n_test] * 1.0, config.resolution))
    outcome = run_sweep(config.replace(scenes=(str(data),)), tmp_path / "results", progress=False)
    assert not outcome.failed and len(outcome.results) == 1
    assert RunKey("data", "ours", 0).folder(tmp_path / "results").joinpath("result.json").is_file()

    (data / "toy_test.json").unlink()  # a missing split is named by the file that would list it
    with pytest.raises(ValueError, match=r"toy_test\.json.*a test split is needed for evaluation: file not found"):
        run_sweep(config.replace(scenes=(str(data),)), tmp_path / "other", progress=False)


def test_registration_ends_with_its_block():
    with register_format(ToyFormat()):
        with pytest.raises(ValueError, match="registered already"):
            with register_format(ToyFormat()):
                pass
    assert "toy" not in FORMATS
    with pytest.raises(ValueError, match="unknown dataset format 'toy'; choose one of: blender, nerfstudio"):
        get_format("toy")

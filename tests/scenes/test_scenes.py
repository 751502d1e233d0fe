"""Tests for nerfaug.scenes: built-in scenes, user .blend files, datasets and their cache."""

import fnmatch
import importlib.util
import json
import math
import os
import shutil
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import imageio.v3 as iio
import pytest
import torch

import nerfaug
from nerfaug.cameras import Cameras
from nerfaug.data import load_dataset
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, angles_from_pose, in_azimuth_window, pose_from_angles
from nerfaug.scenes import BUILTIN_SCENES, builtin, render
from nerfaug.scenes.render import (
    BlenderNotAvailable,
    RenderError,
    dataset_poses,
    render_poses,
    render_scene_dataset,
    render_views,
)

# Never import bpy here: it must not share a process with torch. Only check that it exists.
blender = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy")

POSES = pose_from_angles(torch.tensor([0.4, 2.5, 4.4]), torch.tensor([0.5, 1.0, 1.35]))


def alpha_stats(alpha: torch.Tensor) -> tuple[float, torch.Tensor]:
    """Coverage (fraction of the image) and alpha centroid as a fraction of the size (x, y)."""
    h, w = alpha.shape
    ys, xs = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(w) + 0.5, indexing="ij")
    total = alpha.sum()
    return (total / alpha.numel()).item(), torch.stack([(alpha * xs).sum() / total / w, (alpha * ys).sum() / total / h])


def test_importing_the_package_imports_neither_bpy_nor_torch():
    code = (
        "import sys, nerfaug.scenes, nerfaug.scenes.worker; "
        "assert not {'bpy', 'torch'} & set(sys.modules), sorted({'bpy', 'torch'} & set(sys.modules))"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_oracle_import_does_not_import_bpy():
    subprocess.run([sys.executable, "-c", "import sys, nerfaug.oracle; assert 'bpy' not in sys.modules"], check=True)


def test_missing_bpy_says_how_to_install(monkeypatch, tmp_path):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "bpy" else real(name, *a))
    with pytest.raises(BlenderNotAvailable, match=r"pip install 'nerfaug\[blender\]'"):
        render_scene_dataset("lego", tmp_path / "lego")
    with pytest.raises(BlenderNotAvailable, match="Python 3.11"):
        render_views("lego", POSES, 8, 8)


def test_unknown_scene_lists_the_builtins(tmp_path):
    with pytest.raises(ValueError, match="lego"):
        render.scene_spec("teapot")
    with pytest.raises(ValueError, match="blend"):
        render.scene_spec(tmp_path / "missing.blend")


def test_dataset_poses_follow_the_protocol():
    poses = dataset_poses(pool=50, test=20, initial=6, val=4, seed=3)
    assert {k: len(v) for k, v in poses.items()} == {"train": 50, "initial": 6, "test": 20, "val": 4}
    for split, split_poses in poses.items():
        radius = angles_from_pose(split_poses)[2]
        assert torch.allclose(radius, torch.full_like(radius, 4.0311), atol=1e-3), split
    azimuth, polar, _ = angles_from_pose(poses["initial"])
    assert in_azimuth_window(azimuth, math.pi / 2).all()  # all initial views on one half
    test_azimuth, test_polar, _ = angles_from_pose(poses["test"])
    assert (~in_azimuth_window(test_azimuth, math.pi / 2)).any() and test_polar.max() > 1.3
    assert all(any(torch.equal(v, t) for t in poses["test"]) for v in poses["val"])
    assert torch.equal(dataset_poses(50, 20, 6, 4, seed=3)["train"], poses["train"])
    assert not torch.allclose(dataset_poses(50, 20, 6, 4, seed=4)["train"], poses["train"])


@pytest.mark.parametrize("scene", BUILTIN_SCENES)
@pytest.mark.slow
@pytest.mark.blender
@blender
def test_builtin_scene_is_centred_covers_a_sane_area_and_changes_with_the_view(scene):
    views = render_views(scene, POSES, 40, 40, samples=4, progress=False)
    assert views.images.shape == (3, 40, 40, 3) and views.alphas.shape == (3, 40, 40)
    for alpha in views.alphas:
        coverage, centroid = alpha_stats(alpha)
        assert 0.03 < coverage < 0.7, coverage
        assert (centroid - 0.5).abs().max() < 0.12, centroid
    for i in range(1, 3):
        assert (views.images[i] - views.images[0]).abs().mean() > 0.02


@pytest.mark.slow
@pytest.mark.blender
@blender
def test_same_seed_gives_identical_pixels_and_another_seed_does_not():
    both = render_views("materials", POSES[:2], 32, 32, samples=2, seed=1, progress=False)
    # Rendered alone, as a resumed batch would, the second view comes out the same.
    alone = render_views("materials", POSES[1:2], 32, 32, samples=2, seed=1, progress=False)
    other = render_views("materials", POSES[1:2], 32, 32, samples=2, seed=2, progress=False)
    assert torch.equal(alone.images[0], both.images[1]) and torch.equal(alone.alphas[0], both.alphas[1])
    assert not torch.equal(alone.images, other.images)


def make_blend(path, constrained_camera: bool) -> torch.Tensor:
    """Save a .blend holding one small sphere off the origin (and, optionally, a camera whose
    Track To constraint would aim it elsewhere); return the sphere's centre, shape (3,)."""
    centre = (0.7, -0.4, 0.5)
    script = textwrap.dedent(f"""
        import bpy
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.15, location={centre})
        if {constrained_camera}:
            target = bpy.data.objects.new("target", None)
            bpy.context.scene.collection.objects.link(target)
            target.location = (-1.0, 1.0, 0.0)
            camera = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
            bpy.context.scene.collection.objects.link(camera)
            bpy.context.scene.camera = camera
            camera.constraints.new("TRACK_TO").target = target
        bpy.ops.wm.save_as_mainfile(filepath={str(path)!r})
    """)
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True)
    return torch.tensor(centre)


@pytest.mark.parametrize("constrained_camera", [False, True])
@pytest.mark.slow
@pytest.mark.blender
@blender
def test_blend_file_renders_where_the_cameras_project_it(tmp_path, constrained_camera):
    """The sphere appears where nerfaug.cameras projects its centre: same convention, same field
    of view, no mirroring, and a user camera's constraints do not override the pose."""
    centre = make_blend(tmp_path / "sphere.blend", constrained_camera)
    views = render_views(tmp_path / "sphere.blend", POSES[:2], 40, 32, samples=2, progress=False)
    cameras = Cameras.from_fov(POSES[:2], BLENDER_CAMERA_ANGLE_X, 40, 32)
    for i in range(2):
        local = torch.linalg.inv(cameras.camera_to_world[i]) @ torch.cat([centre, torch.ones(1)])
        x = cameras.cx[i] + cameras.fx[i] * local[0] / -local[2]
        y = cameras.cy[i] - cameras.fy[i] * local[1] / -local[2]
        _, centroid = alpha_stats(views.alphas[i])
        assert torch.allclose(centroid * torch.tensor([40.0, 32.0]), torch.stack([x, y]), atol=0.3)


@pytest.mark.slow
@pytest.mark.blender
@blender
def test_a_failing_worker_raises_with_its_output(tmp_path):
    (tmp_path / "broken.blend").write_bytes(b"not a blend file")
    with pytest.raises(RenderError, match="exited with code"):
        render_views(tmp_path / "broken.blend", POSES[:1], 8, 8, progress=False)


@pytest.mark.slow
@pytest.mark.blender
@blender
def test_render_poses_skips_frames_already_rendered(tmp_path, monkeypatch):
    counts = []
    run_worker = render._run_worker
    monkeypatch.setattr(render, "_run_worker", lambda job, n, *a: (counts.append(n), run_worker(job, n, *a)))
    done = tmp_path / "a.png"
    done.write_bytes(b"kept")
    render_poses("chair", POSES[:2], [done, tmp_path / "b.png"], 16, 16, samples=1, progress=False)
    assert counts == [1] and done.read_bytes() == b"kept" and (tmp_path / "b.png").is_file()


@pytest.mark.slow
@pytest.mark.blender
@blender
def test_dataset_reads_back_is_cached_and_rerenders_on_new_arguments(tmp_path, monkeypatch):
    out = tmp_path / "chair"
    args = dict(resolution=32, pool=5, test=4, initial=2, val=2, samples=2, seed=0, progress=False)
    assert render_scene_dataset("chair", out, **args) == out
    expected = dataset_poses(5, 4, 2, 2, seed=0)
    for split, n in {"train": 5, "initial": 2, "test": 4, "val": 2}.items():
        views = load_dataset(out, split)
        assert len(views) == n and views.images.shape == (n, 32, 32, 3) and views.alphas is not None
        assert torch.allclose(views.cameras.camera_to_world, expected[split], atol=1e-6)
        assert torch.allclose(views.cameras.camera_angle_x, torch.tensor(BLENDER_CAMERA_ANGLE_X))
        assert (views.alphas.mean(dim=(1, 2)) > 0.03).all()
    val, test = load_dataset(out, "val"), load_dataset(out, "test")
    assert torch.equal(val.images[0], test.images[0])
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # no staging left behind

    mtimes = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    monkeypatch.setattr(render, "_run_worker", lambda *a: pytest.fail("rendered a cached dataset"))
    render_scene_dataset("chair", out, **args)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == mtimes
    monkeypatch.undo()

    (out / "train" / "r_3.png").unlink()  # an incomplete dataset is not a cache hit
    assert not render.is_complete(out, render.dataset_manifest({"builtin": "chair"}, 32, 5, 4, 2, 2, 2, 0))
    render_scene_dataset("chair", out, **{**args, "samples": 3})
    assert load_dataset(out, "train").images.shape[0] == 5
    assert '"samples": 3' in (out / "scene.json").read_text()


@blender
def test_dataset_refuses_to_replace_a_foreign_folder(tmp_path):
    (tmp_path / "mine.txt").write_text("precious")
    with pytest.raises(FileExistsError, match="scene.json"):
        render_scene_dataset("lego", tmp_path, resolution=8, pool=1, test=1, initial=1)
    assert (tmp_path / "mine.txt").read_text() == "precious"


@blender
def test_a_rendered_dataset_holding_a_users_file_is_not_replaced(tmp_path):
    """A dataset rendered with other arguments is replaced, unless a user put a file of their own
    into it: then nothing is rendered or removed, and the refusal names the file."""
    out = tmp_path / "lego"
    (out / "train").mkdir(parents=True)
    (out / "scene.json").write_text(json.dumps({"resolution": 4}))
    (out / "transforms_train.json").write_text(json.dumps({"frames": []}))
    (out / "train" / "r_0.png").write_bytes(b"png")
    (out / "train" / "notes.md").write_text("mine")
    with pytest.raises(FileExistsError, match=r"lego: holds train/notes\.md, which nerfaug did not write"):
        render_scene_dataset("lego", out, resolution=8, pool=1, test=1, initial=1, progress=False)
    assert (out / "train" / "notes.md").read_text() == "mine" and (out / "scene.json").is_file()


# ---- the cow: a built-in scene built from files shipped with the package -------------------------

ROOT = Path(__file__).resolve().parents[2]


def test_cow_files_are_real_packaged_and_carry_their_licence():
    folder = builtin.ASSETS / "cow"
    obj, mtl, texture = (folder / name for name in builtin.BUILTIN_ASSETS["cow"])
    # Real files, not Git LFS pointers: a triangle mesh with UVs, a material naming the texture.
    lines = obj.read_text().splitlines()
    assert "mtllib cow.mtl" in lines and sum(line.startswith("f ") for line in lines) == 5856
    assert sum(line.startswith("vt ") for line in lines) > 0
    assert "map_Kd cow_texture.png" in mtl.read_text()
    assert iio.imread(texture).shape == (1024, 1024, 3)
    note = (folder / "README.md").read_text()
    assert "public domain" in note and "Keenan Crane" in note and "kmcrane/Projects/ModelRepository" in note
    # A non-editable install ships them: pyproject's package data covers every file of the folder.
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["nerfaug"]
    package = Path(nerfaug.__file__).parent
    for path in folder.iterdir():
        assert any(fnmatch.fnmatch(path.relative_to(package).as_posix(), p) for p in patterns), path


def test_manifest_holds_the_digest_of_the_cow_files(tmp_path, monkeypatch):
    def manifest(scene):
        return render.dataset_manifest({"builtin": scene}, 32, 5, 4, 2, 2, 2, 0)

    assert "assets_sha256" not in manifest("lego")["scene"]
    before = manifest("cow")
    assert len(before["scene"]["assets_sha256"]) == 64 and before == manifest("cow")
    shutil.copytree(builtin.ASSETS, tmp_path / "assets")
    monkeypatch.setattr(builtin, "ASSETS", tmp_path / "assets")
    assert manifest("cow") == before
    (tmp_path / "assets" / "cow" / "README.md").write_text("a note does not change the pixels")
    assert manifest("cow") == before
    texture = tmp_path / "assets" / "cow" / "cow_texture.png"
    texture.write_bytes(texture.read_bytes() + b"\0")  # any edit of a file the cow is built from
    assert manifest("cow")["scene"]["assets_sha256"] != before["scene"]["assets_sha256"]
    assert manifest("cow")["scene_code_sha256"] == before["scene_code_sha256"]
    texture.unlink()
    with pytest.raises(FileNotFoundError, match="cow_texture.png"):
        manifest("cow")


COW_REPORT = """
import json
import bpy
from nerfaug.scenes import builders
builders.load_scene({"builtin": "cow"})
bpy.context.view_layer.update()
(cow,) = (o for o in bpy.context.scene.objects if o.type == "MESH")
points = [cow.matrix_world @ v.co for v in cow.data.vertices]
top = sorted(points, key=lambda p: -p.z)[:20]  # the horns, on the head
link = cow.active_material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].links[0]
print("COW", json.dumps({
    "low": [min(p[k] for p in points) for k in range(3)],
    "high": [max(p[k] for p in points) for k in range(3)],
    "horns_x": sum(p.x for p in top) / len(top),
    "smooth": all(face.use_smooth for face in cow.data.polygons),
    "base_colour_from": link.from_node.type,
    "texture": [link.from_node.image.filepath, *link.from_node.image.size],
}))
"""


@pytest.mark.slow
@pytest.mark.blender
@blender
def test_cow_is_textured_z_up_and_fits_the_box():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(Path(nerfaug.__file__).parents[1]), env.get("PYTHONPATH")) if p)
    done = subprocess.run([sys.executable, "-c", COW_REPORT], check=True, capture_output=True, text=True, env=env)
    cow = json.loads(done.stdout.split("COW ", 1)[1])
    low, high = torch.tensor(cow["low"]), torch.tensor(cow["high"])
    assert torch.allclose(low + high, torch.zeros(3), atol=1e-4)  # centred
    assert abs((high - low).max().item() / 2 - 1.1) < 1e-4  # largest half-side 1.1: inside [-1.1, 1.1]^3
    length, width, height = (high - low).tolist()
    assert width < 0.65 * min(length, height), (length, width, height)  # z up, seen side-on from +-y
    assert cow["horns_x"] > 0.3  # the head towards +x
    assert cow["smooth"] and cow["base_colour_from"] == "TEX_IMAGE"
    assert cow["texture"][0].endswith("cow_texture.png") and cow["texture"][1:] == [1024, 1024]


@pytest.mark.slow
@pytest.mark.blender
@blender
def test_cow_renders_its_spots():
    """Mostly white with dark spots: with the texture unplugged (a flat white cow, measured once)
    the darkest 5% of its opaque pixels are still brighter than 0.6; textured, below 0.4."""
    views = render_views("cow", POSES, 40, 40, samples=4, progress=False)
    for image, alpha in zip(views.images, views.alphas):
        luminance = image[alpha > 0.99].mean(-1)
        dark, median = torch.quantile(luminance, torch.tensor([0.05, 0.5])).tolist()
        assert dark < 0.5 and median > 0.55, (dark, median)


def test_a_mistyped_scene_is_answered_with_the_closest_built_in_one(tmp_path, monkeypatch):
    from nerfaug.experiment.protocol import scene_folder
    from nerfaug.scenes.render import scene_spec

    with pytest.raises(ValueError, match="unknown scene 'lgo': did you mean 'lego'\\? expected one of lego, chair"):
        scene_spec("lgo")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="unknown scene 'chiar': did you mean 'chair'\\? not a dataset folder"):
        scene_folder("chiar")
    with pytest.raises(ValueError, match="unknown scene 'teapot': not a dataset folder"):  # nothing close
        scene_folder("teapot")

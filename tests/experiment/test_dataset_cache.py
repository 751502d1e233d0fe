"""The on-disk cache of downscaled datasets: used, invalidated by any change of the source, and
bit-for-bit the images an uncached load gives."""

import torch

import nerfaug.data.frames as frames
from nerfaug.cameras import Cameras
from nerfaug.data import Views, load_dataset, write_blender_split
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.protocol import load_scene_data
from nerfaug.hemisphere import sample_uniform_poses
from nerfaug.scenes.cache import folder_digest, load_split_cached


def write_dataset(root, seed=0, size=16, n_train=10, n_test=4):
    generator = torch.Generator().manual_seed(seed)
    for split, n in (("train", n_train), ("test", n_test)):
        poses = sample_uniform_poses(n, generator)
        images = torch.rand(n, size, size, 3, generator=generator)
        alphas = torch.rand(n, size, size, generator=generator)
        names = [f"r_{i}" for i in range(n)]
        write_blender_split(root, split, Views(Cameras.from_fov(poses, 0.69, size, size), images, names, alphas))
    return root


def count_reads(monkeypatch) -> list:
    calls = []
    original = frames.read_image

    def counted(*args, **kwargs):
        calls.append(args[0])
        return original(*args, **kwargs)

    monkeypatch.setattr(frames, "read_image", counted)
    return calls


def assert_same_views(a: Views, b: Views):
    assert torch.equal(a.images, b.images)
    assert (a.alphas is None) == (b.alphas is None)
    if a.alphas is not None:
        assert torch.equal(a.alphas, b.alphas)
    assert a.names == b.names
    assert torch.equal(a.cameras.camera_to_world, b.cameras.camera_to_world)
    assert torch.equal(a.cameras.fx, b.cameras.fx) and (a.cameras.width, a.cameras.height) == (
        b.cameras.width,
        b.cameras.height,
    )


def test_cached_split_equals_an_uncached_load_and_is_read_from_the_cache(tmp_path, monkeypatch):
    data = write_dataset(tmp_path / "data")
    cache = tmp_path / "cache"
    reference = load_dataset(data, "train", downscale=2)
    first = load_split_cached(data, "train", 2, cache)
    assert_same_views(first, reference)
    assert len(list(cache.glob("*.pt"))) == 1

    calls = count_reads(monkeypatch)
    second = load_split_cached(data, "train", 2, cache)
    assert_same_views(second, reference)
    assert len(calls) == 1  # only the lazy probe of frame 0 (for the image size), not 10 images


def test_other_factor_or_split_is_another_entry(tmp_path):
    data = write_dataset(tmp_path / "data")
    cache = tmp_path / "cache"
    assert_same_views(load_split_cached(data, "train", 1, cache), load_dataset(data, "train"))
    assert_same_views(load_split_cached(data, "train", 4, cache), load_dataset(data, "train", downscale=4))
    assert_same_views(load_split_cached(data, "test", 4, cache), load_dataset(data, "test", downscale=4))
    assert len(list(cache.glob("*.pt"))) == 3


def test_a_changed_image_invalidates_the_cache(tmp_path, monkeypatch):
    data = write_dataset(tmp_path / "data")
    cache = tmp_path / "cache"
    before = load_split_cached(data, "train", 2, cache)
    digest = folder_digest(data)
    # Replace one image by another dataset's (same size and name): only its bytes change.
    other = write_dataset(tmp_path / "other", seed=1)
    (data / "train" / "r_3.png").write_bytes((other / "train" / "r_3.png").read_bytes())
    assert folder_digest(data) != digest

    calls = count_reads(monkeypatch)
    after = load_split_cached(data, "train", 2, cache)
    assert len(calls) == 10  # decoded again
    assert_same_views(after, load_dataset(data, "train", downscale=2))
    assert not torch.equal(after.images[3], before.images[3])
    assert torch.equal(after.images[2], before.images[2])


def test_digest_ignores_hidden_files_and_sees_new_ones(tmp_path):
    data = write_dataset(tmp_path / "data")
    digest = folder_digest(data)
    (data / ".partial").mkdir()
    (data / ".partial" / "x.png").write_bytes(b"junk")
    assert folder_digest(data) == digest
    (data / "notes.txt").write_text("new")
    assert folder_digest(data) != digest


def test_scene_data_is_the_same_with_and_without_the_cache(tmp_path, monkeypatch):
    data = write_dataset(tmp_path / "data", size=32, n_train=12)
    config = ExperimentConfig(resolution=16, n_initial=3, n_test=3)
    plain = load_scene_data(data, config)
    cached = load_scene_data(data, config, cache_dir=tmp_path / "cache")
    calls = count_reads(monkeypatch)
    again = load_scene_data(data, config, cache_dir=tmp_path / "cache")
    assert len(calls) <= 3  # lazy probes only
    for views in (cached, again):
        assert_same_views(views.initial, plain.initial)
        assert_same_views(views.pool, plain.pool)
        assert_same_views(views.test, plain.test)
    assert plain.test.images.shape == (3, 16, 16, 3)


def test_a_damaged_entry_is_rebuilt(tmp_path):
    data = write_dataset(tmp_path / "data")
    cache = tmp_path / "cache"
    load_split_cached(data, "train", 2, cache)
    (entry,) = cache.glob("*.pt")
    entry.write_bytes(entry.read_bytes()[:100])  # truncated
    assert_same_views(load_split_cached(data, "train", 2, cache), load_dataset(data, "train", downscale=2))
    assert torch.load(entry, weights_only=True)["images"].shape == (10, 8, 8, 3)  # rewritten whole

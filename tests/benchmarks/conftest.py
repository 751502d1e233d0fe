"""Shared by the benchmark scripts' tests: the script a test module names, loaded as a module, and
a toy Blender-format dataset (an analytic sphere) with initial, train and test splits, made
without Blender."""

import importlib.util
import sys
from pathlib import Path

import pytest
import torch

from nerfaug.data import write_blender_split
from nerfaug.hemisphere import half_hemisphere_poses, sample_uniform_poses
from nerfaug.scenes.sphere import sphere_views


@pytest.fixture(scope="module")
def bench(request):
    """The script `SCRIPT` of the requesting test module, as a module. benchmarks/ holds scripts,
    not a package; it joins sys.path, as it is when a script runs, so scripts import each other."""
    script = request.module.SCRIPT
    if str(script.parent) not in sys.path:
        sys.path.insert(0, str(script.parent))
    spec = importlib.util.spec_from_file_location(script.stem, script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("toy") / "sphere"
    write_blender_split(root, "initial", sphere_views(half_hemisphere_poses(3), "i"))
    write_blender_split(root, "train", sphere_views(sample_uniform_poses(8, torch.Generator().manual_seed(0)), "r"))
    write_blender_split(root, "test", sphere_views(sample_uniform_poses(4, torch.Generator().manual_seed(1)), "t"))
    return root

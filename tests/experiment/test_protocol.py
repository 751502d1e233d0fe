import dataclasses
import math

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import Views
from nerfaug.experiment.config import PROTOCOL_PRESETS, STUDY_PRESETS, ExperimentConfig
from nerfaug.hemisphere import angles_from_pose, in_azimuth_window, sample_uniform_poses
from nerfaug.layouts import initial_in_half, layout_halves


def test_paper_field_learning_rate_for_chair_and_materials():
    config = ExperimentConfig(engine="cpu")
    assert config.engine_config("chair").optimiser.field_lr == 0.002
    assert config.engine_config("/data/nerf_synthetic/materials").optimiser.field_lr == 0.002
    assert config.engine_config("lego").optimiser.field_lr != 0.002


def test_initial_views_of_a_user_dataset_lie_on_one_half():
    poses = sample_uniform_poses(300, torch.Generator().manual_seed(0))
    half = layout_halves(angles_from_pose(poses)[0], 1)[0]
    chosen = initial_in_half(poses, 6, half, list(range(300)))
    assert len(set(chosen)) == 6
    azimuth, _, _ = angles_from_pose(poses[chosen])
    assert in_azimuth_window(azimuth, math.pi / 2, math.pi).all()
    assert chosen == initial_in_half(poses, 6, half, list(range(300)))  # the same views for every trial
    outside = [i for i in range(300) if not bool(half.contains(angles_from_pose(poses[i : i + 1])[0])[0])]
    with pytest.raises(ValueError, match="only 2 views lie in the half"):
        initial_in_half(poses, 6, half, chosen[:2] + outside)


def test_presets_are_consistent():
    for name in ("quick", "paper", "ablation", "tiny"):
        config = PROTOCOL_PRESETS.choose(name)
        assert 0 < config.add_at_step < config.steps
        assert config.n_new <= config.pool


def test_a_preset_is_a_fresh_copy_of_its_config_and_an_unknown_name_lists_the_known_ones():
    tiny = PROTOCOL_PRESETS.choose("tiny")
    assert tiny == PROTOCOL_PRESETS["tiny"] and tiny is not PROTOCOL_PRESETS["tiny"]
    tiny.field_lr["lego"] = 1.0  # a config is mutable: changing a copy leaves the preset alone
    assert "lego" not in PROTOCOL_PRESETS.choose("tiny").field_lr
    assert (tiny.trials, tiny.steps, str(tiny.engine)) == (2, 60, "test")
    assert PROTOCOL_PRESETS.choose("tiny", trials=3).trials == 3
    assert STUDY_PRESETS.choose("tiny") == PROTOCOL_PRESETS.choose("tiny").replace(view_uncertainty=False)
    with pytest.raises(ValueError, match="unknown preset 'fast'; choose one of: quick, paper, ablation, tiny"):
        PROTOCOL_PRESETS.choose("fast")


def test_quick_preset_compares_the_main_methods_with_enough_trials_for_significance():
    from scipy.stats import mannwhitneyu

    from nerfaug.evaluation import Lpips
    from nerfaug.experiment.config import MAIN_COMPARISON

    config = PROTOCOL_PRESETS.choose("quick")
    assert config.methods == MAIN_COMPARISON and len(config.methods) == 4
    # The smallest p of a two-sided Mann-Whitney test (complete separation), times the 3
    # comparisons of "ours" with the others, must be able to fall below 0.05.
    ours, other = list(range(config.trials)), list(range(100, 100 + config.trials))
    assert 3 * mannwhitneyu(ours, other, alternative="two-sided").pvalue < 0.05
    assert config.resolution >= Lpips.min_size  # LPIPS is reported
    assert config.add_at_step == 200 and config.n_initial == config.n_new == 6  # the paper's protocol
    assert config.engine == "cpu" and config.n_test >= 20


def test_a_run_saves_its_first_test_view_uncertainty_without_changing_its_results(tmp_path):
    """The view's arrays are written after the evaluation: the same run without them has the
    same metrics, selection and history, bit for bit."""
    import json

    import numpy as np

    from nerfaug.data import write_blender_split
    from nerfaug.experiment import protocol
    from nerfaug.experiment.runfolder import FILES, read_view_uncertainty
    from nerfaug.experiment.store import RunKey
    from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X

    size, generator = 24, torch.Generator().manual_seed(0)
    data = tmp_path / "data"
    for split, n in (("train", 12), ("test", 2), ("initial", 3)):
        poses = sample_uniform_poses(n, generator)
        images = torch.rand(n, size, size, 3, generator=generator)
        cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size)
        write_blender_split(data, split, Views(cameras, images, [f"./{split}/r_{i}" for i in range(n)]))
    config = PROTOCOL_PRESETS.choose("tiny").replace(steps=30, add_at_step=10, n_test=2, threads_per_run=1)
    config = config.replace(
        selection=dataclasses.replace(config.selection, fisher_resolution=4, fisher_train_pixels=64)
    )
    key = RunKey("scene", "fisherrf", 0)

    with_maps = protocol.run_trial(key, data, config, tmp_path / "with")
    arrays = read_view_uncertainty(key.folder(tmp_path / "with"))
    assert arrays is not None and set(arrays) == {"render", "error", "entropy", "fisher"}
    assert arrays["render"].shape == (size, size, 3) and arrays["error"].shape == arrays["entropy"].shape == (
        size,
        size,
    )
    assert arrays["fisher"].shape == (size, size)  # VIEW_FISHER_WIDTH (24) is not above the view's width
    assert (arrays["error"] >= 0).all() and (arrays["entropy"] >= 0).all() and (arrays["fisher"] >= 0).all()
    assert arrays["fisher"].sum() > 0 and "view_uncertainty" in with_maps["timing"]

    without = protocol.run_trial(key, data, config.replace(view_uncertainty=False), tmp_path / "without")
    assert not (key.folder(tmp_path / "without") / FILES.view_uncertainty).exists()
    assert "view_uncertainty" not in without["timing"]
    assert with_maps["metrics"] == without["metrics"] and with_maps["chosen"] == without["chosen"]
    for name in (FILES.selection, FILES.metrics, FILES.history):
        first, second = (json.loads((key.folder(tmp_path / r) / name).read_text()) for r in ("with", "without"))
        assert first == second, name
    # The error image is the render's against the test image the metrics were computed on.
    per_view = json.loads((key.folder(tmp_path / "with") / FILES.metrics).read_text())["per_view"][0]
    assert -10 * np.log10(arrays["error"].mean()) == pytest.approx(per_view["psnr"], abs=0.05)


def test_view_uncertainty_of_older_runs_reads_as_absent(tmp_path):
    import numpy as np

    from nerfaug.experiment.runfolder import FILES, read_view_uncertainty, write_view_uncertainty

    assert read_view_uncertainty(tmp_path) is None
    write_view_uncertainty(tmp_path, {"render": np.zeros((4, 4, 3)), "error": np.zeros((4, 4))})
    assert read_view_uncertainty(tmp_path) is None  # no entropy
    write_view_uncertainty(tmp_path, {"entropy": np.zeros((4, 4)), "fisher": np.zeros((8, 8))})
    found = read_view_uncertainty(tmp_path)
    assert set(found) == {"render", "error", "entropy"}  # a FisherRF image larger than the view is left out
    (tmp_path / FILES.view_uncertainty / "error.npy").write_bytes(b"not an array")
    assert read_view_uncertainty(tmp_path) is None
    with pytest.raises(ValueError, match="unknown view array 'depth'"):
        write_view_uncertainty(tmp_path, {"depth": np.zeros((4, 4))})


def test_a_sweeps_run_trains_and_selects_on_its_own_thread_count(tmp_path, monkeypatch):
    """A sweep runs many trials at once, one per core: each run's torch must keep to
    `threads_per_run` (1 by default) whatever the process had, through training and selection."""
    from nerfaug.data import write_blender_split
    from nerfaug.experiment import protocol
    from nerfaug.experiment.store import RunKey
    from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X

    assert ExperimentConfig().threads_per_run == 1
    generator = torch.Generator().manual_seed(0)
    for split, n in (("train", 8), ("test", 2), ("initial", 3)):
        cameras = Cameras.from_fov(sample_uniform_poses(n, generator), BLENDER_CAMERA_ANGLE_X, 8, 8)
        images = torch.rand(n, 8, 8, 3, generator=generator)
        write_blender_split(tmp_path / "data", split, Views(cameras, images, [f"./{split}/r_{i}" for i in range(n)]))
    seen = []
    train = protocol.train_with_progress
    original_select = protocol.select_views

    def counting_train(*args, **kwargs):
        seen.append(("train", torch.get_num_threads()))
        return train(*args, **kwargs)

    def counting_select(*args, **kwargs):
        seen.append(("select", torch.get_num_threads()))
        return original_select(*args, **kwargs)

    monkeypatch.setattr(protocol, "train_with_progress", counting_train)
    monkeypatch.setattr(protocol, "select_views", counting_select)
    config = PROTOCOL_PRESETS.choose("tiny").replace(steps=12, add_at_step=6, n_test=2, n_new=2, view_uncertainty=False)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        protocol.run_trial(RunKey("scene", "uniform", 0), tmp_path / "data", config, tmp_path / "runs")
    finally:
        torch.set_num_threads(before)
    assert {kind for kind, _ in seen} == {"train", "select"}
    assert all(threads == 1 for _, threads in seen), seen

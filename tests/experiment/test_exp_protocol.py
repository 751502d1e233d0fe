import math

import torch

from nerfaug.cameras import Cameras
from nerfaug.data import Views
from nerfaug.experiment.config import ExperimentConfig, preset
from nerfaug.experiment.protocol import engine_config, initial_view_indices
from nerfaug.hemisphere import angles_from_pose, in_azimuth_window, sample_uniform_poses


def test_paper_field_learning_rate_for_chair_and_materials():
    config = ExperimentConfig(engine="cpu")
    assert engine_config(config, "chair").field_lr == 0.002
    assert engine_config(config, "/data/nerf_synthetic/materials").field_lr == 0.002
    assert engine_config(config, "lego").field_lr != 0.002


def test_initial_views_of_a_user_dataset_lie_on_one_half():
    poses = sample_uniform_poses(300, torch.Generator().manual_seed(0))
    pool = Views(Cameras.from_fov(poses, 0.69, 8, 8), torch.zeros(300, 8, 8, 3), [str(i) for i in range(300)])
    chosen = initial_view_indices(pool, 6)
    assert len(set(chosen)) == 6
    azimuth, _, _ = angles_from_pose(poses[chosen])
    assert in_azimuth_window(azimuth, math.pi / 2 - 0.3, math.pi + 0.6).all()
    assert chosen == initial_view_indices(pool, 6)  # the same views for every trial


def test_presets_are_consistent():
    for name in ("quick", "paper", "ablation", "tiny"):
        config = preset(name)
        assert 0 < config.add_at_step < config.steps
        assert config.n_new <= config.pool


def test_quick_preset_compares_the_main_methods_with_enough_trials_for_significance():
    from scipy.stats import mannwhitneyu

    from nerfaug.evaluation import Lpips
    from nerfaug.experiment.config import MAIN_COMPARISON

    config = preset("quick")
    assert config.methods == MAIN_COMPARISON and len(config.methods) == 4
    # The smallest p of a two-sided Mann-Whitney test (complete separation), times the 3
    # comparisons of "ours" with the others, must be able to fall below 0.05.
    ours, other = list(range(config.trials)), list(range(100, 100 + config.trials))
    assert 3 * mannwhitneyu(ours, other, alternative="two-sided").pvalue < 0.05
    assert config.resolution >= Lpips.min_size  # LPIPS is reported
    assert config.add_at_step == 200 and config.n_initial == config.n_new == 6  # the paper's protocol
    assert config.engine == "cpu" and config.n_test >= 20

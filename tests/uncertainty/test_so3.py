import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from nerfaug.hemisphere import pose_from_angles
from nerfaug.uncertainty.so3 import coverage_distance, min_geodesic_angle, so3_geodesic_sq, so3_log


def rotvecs_with_hard_angles(n: int, seed: int) -> np.ndarray:
    """Random axes with angles spread over [0, pi], within 1e-6 (and closer) of 0 and of pi."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    k = n // 4
    angles = np.concatenate(
        [
            rng.uniform(0.0, math.pi, n - 3 * k),
            math.pi - 10.0 ** rng.uniform(-12, -6, k),
            10.0 ** rng.uniform(-12, -6, k),
            np.array([0.0, math.pi, math.pi - 1e-6, 1e-6] * (k // 4 + 1))[:k],
        ]
    )
    return axes * angles[:, None]


def test_log_matches_scipy_rotvec_up_to_sign_at_pi():
    rotvec = rotvecs_with_hard_angles(800, seed=0)
    matrices = Rotation.from_rotvec(rotvec).as_matrix()
    log = so3_log(torch.from_numpy(matrices)).numpy()
    angles = np.linalg.norm(rotvec, axis=1)
    error = np.linalg.norm(log - rotvec, axis=1)
    # At pi, r and -r are the same rotation; elsewhere the sign must match.
    flipped = np.linalg.norm(log + rotvec, axis=1)
    near_pi = angles > math.pi - 1e-5
    error = np.where(near_pi, np.minimum(error, flipped), error)
    assert error.max() < 1e-9
    assert (np.linalg.norm(log[~near_pi] - rotvec[~near_pi], axis=1) < 1e-9).all()


def test_log_of_identity_is_zero_and_batched_shapes_are_kept():
    assert torch.equal(so3_log(torch.eye(3, dtype=torch.float64)), torch.zeros(3, dtype=torch.float64))
    batch = torch.from_numpy(Rotation.random(6, random_state=1).as_matrix()).reshape(2, 3, 3, 3)
    assert so3_log(batch).shape == (2, 3, 3)


def test_geodesic_matches_scipy_relative_magnitude():
    a = Rotation.random(400, random_state=2)
    # b = a * relative rotation with hard angles, plus fully random pairs.
    relative = Rotation.from_rotvec(rotvecs_with_hard_angles(400, seed=3))
    b = a * relative
    b_random = Rotation.random(400, random_state=4)
    for other in (b, b_random):
        expected = (a.inv() * other).magnitude()
        ours = so3_geodesic_sq(torch.from_numpy(a.as_matrix()), torch.from_numpy(other.as_matrix())).sqrt()
        assert np.abs(ours.numpy() - expected).max() < 1e-8


def test_geodesic_in_float32_is_accurate_near_zero_and_pi():
    relative = Rotation.from_rotvec(rotvecs_with_hard_angles(400, seed=5))
    a = Rotation.random(400, random_state=6)
    expected = relative.magnitude()
    ours = so3_geodesic_sq(
        torch.from_numpy(a.as_matrix()).float(), torch.from_numpy((a * relative).as_matrix()).float()
    ).sqrt()
    assert np.abs(ours.double().numpy() - expected).max() < 2e-3  # float32 matrix entries
    near_zero = expected < 1e-3
    assert np.abs(ours.double().numpy()[near_zero] - expected[near_zero]).max() < 1e-6


def test_metric_weights_the_log_coordinates():
    a = torch.eye(3, dtype=torch.float64)
    b = torch.from_numpy(Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix())
    metric = torch.diag(torch.tensor([1.0, 4.0, 9.0], dtype=torch.float64))
    expected = 0.1**2 + 4 * 0.2**2 + 9 * 0.3**2
    assert so3_geodesic_sq(a, b, metric).item() == pytest.approx(expected, rel=1e-12)
    with pytest.raises(ValueError, match="metric"):
        so3_geodesic_sq(a, b, torch.eye(2))


def test_coverage_is_zero_at_the_training_view_and_grows_with_angle():
    training = pose_from_angles(torch.tensor([0.5]), torch.tensor([0.7]))[:, :3, :3].double()
    # Candidates rotated away from the training view about a fixed axis by increasing angles.
    angles = torch.linspace(0.0, math.pi - 1e-3, 50, dtype=torch.float64)
    axis = torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64)
    turns = torch.from_numpy(Rotation.from_rotvec((angles[:, None] * axis / axis.norm()).numpy()).as_matrix())
    candidates = training @ turns
    distance = coverage_distance(candidates, training)
    assert distance[0].item() == pytest.approx(0.0, abs=1e-20)
    assert torch.all(distance[1:] > distance[:-1])
    assert torch.allclose(distance, 0.5 * angles**2, atol=1e-10)


def test_coverage_sums_over_training_views():
    rotations = torch.from_numpy(Rotation.random(7, random_state=7).as_matrix())
    candidates, training = rotations[:4], rotations[4:]
    total = coverage_distance(candidates, training)
    parts = sum(0.5 * so3_geodesic_sq(t, candidates) for t in training)
    assert torch.allclose(total, parts, atol=1e-12)
    assert torch.equal(coverage_distance(candidates, training[:0]), torch.zeros(4, dtype=torch.float64))


def test_min_geodesic_angle_is_the_nearest_reference():
    rotations = torch.from_numpy(Rotation.random(9, random_state=8).as_matrix())
    candidates, reference = rotations[:5], rotations[5:]
    nearest = min_geodesic_angle(candidates, reference)
    full = torch.stack([so3_geodesic_sq(r, candidates).sqrt() for r in reference]).min(dim=0).values
    assert torch.allclose(nearest, full, atol=1e-12)

import numpy as np
import pytest
from numdiff import central_difference

from sclam_ros.core import se2

rng = np.random.default_rng(1)


def random_poses(n):
    return np.column_stack([rng.normal(0, 2, (n, 2)), rng.uniform(-np.pi, np.pi, n)])


def test_wrap_angle_range():
    angles = np.array([-np.pi, np.pi, 3 * np.pi, -3 * np.pi, 0.1, 7.0])
    wrapped = se2.wrap_angle(angles)
    assert np.all(wrapped > -np.pi) and np.all(wrapped <= np.pi)
    assert np.allclose(np.exp(1j * wrapped), np.exp(1j * angles))
    assert se2.wrap_angle(-np.pi) == pytest.approx(np.pi)


def test_compose_inverse_between_agree_with_matrices():
    for a, b in zip(random_poses(20), random_poses(20)):
        ma, mb = se2.to_matrix(a), se2.to_matrix(b)
        assert np.allclose(se2.to_matrix(se2.compose(a, b)), ma @ mb)
        assert np.allclose(se2.to_matrix(se2.inverse(a)), np.linalg.inv(ma))
        # a ⊖ b = b⁻¹ ∘ a
        assert np.allclose(se2.to_matrix(se2.between(a, b)), np.linalg.inv(mb) @ ma)
        assert np.allclose(se2.compose(b, se2.between(a, b))[:2], a[:2])


def test_between_of_motion_is_motion():
    start = np.array([1.0, 2.0, 0.5])
    motion = np.array([0.3, -0.1, 0.2])
    end = se2.compose(start, motion)
    assert np.allclose(se2.between(end, start), motion)


def test_compose_jacobians_match_central_differences():
    for a, b in zip(random_poses(10), random_poses(10)):
        _, ja, jb = se2.compose_with_jacobians(a, b)
        assert np.allclose(ja, central_difference(lambda x: se2.compose(x, b), a), atol=1e-7)
        assert np.allclose(jb, central_difference(lambda x: se2.compose(a, x), b), atol=1e-7)


def test_between_jacobians_match_central_differences():
    for a, b in zip(random_poses(10), random_poses(10)):
        _, ja, jb = se2.between_with_jacobians(a, b)
        assert np.allclose(ja, central_difference(lambda x: se2.between(x, b), a), atol=1e-7)
        assert np.allclose(jb, central_difference(lambda x: se2.between(a, x), b), atol=1e-7)


def test_stacked_jacobians_match_single():
    a, b = random_poses(5), random_poses(5)
    _, ja, jb = se2.between_with_jacobians(a, b)
    for i in range(5):
        _, ja1, jb1 = se2.between_with_jacobians(a[i], b[i])
        assert np.allclose(ja[i], ja1) and np.allclose(jb[i], jb1)


def test_chain_equals_composing_one_motion_after_another():
    rng = np.random.default_rng(7)
    motion = rng.normal(0, [0.3, 0.1, 1.5], (50, 3))
    pose, expected = np.zeros(3), [np.zeros(3)]
    for m in motion[1:]:
        pose = se2.compose(pose, m)
        expected.append(pose)
    assert np.allclose(se2.chain(motion), expected, atol=1e-12)

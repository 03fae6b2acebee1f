"""SE(2) algebra on poses stored as numpy arrays (x, y, theta).

Conventions (see GUIDE.md):
  ``compose(a, b)``  = a ⊕ b, b expressed in a's frame, composed onto a;
  ``between(a, b)``  = a ⊖ b = b⁻¹ ∘ a, i.e. pose a expressed in the frame of b,
  so ``between(x_next, x_prev)`` is the motion from x_prev to x_next.

Every function accepts a single pose of shape (3,) or a stack of shape (N, 3) and
broadcasts, because the factors evaluate all edges of one type at once.
"""
from __future__ import annotations

import math

import numpy as np

# Generator of so(2): d/dθ R(θ) = R(θ) @ S and d/dθ R(θ)ᵀ = -S @ R(θ)ᵀ.
S = np.array([[0.0, -1.0], [1.0, 0.0]])


def wrap_angle(angle):
    """Wrap angles to (-π, π]."""
    wrapped = np.mod(np.asarray(angle, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    # np.mod maps +π to -π; the convention is the half-open interval (-π, π].
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def rotation(theta):
    """Rotation matrices R(θ), shape (..., 2, 2)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def rotate(theta, vec):
    """R(θ) @ vec for stacks of angles (...,) and vectors (..., 2)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([c * vec[..., 0] - s * vec[..., 1], s * vec[..., 0] + c * vec[..., 1]], -1)


def rotate_inverse(theta, vec):
    """R(θ)ᵀ @ vec."""
    return rotate(-np.asarray(theta), vec)


def compose(a, b):
    """a ⊕ b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = a[..., :2] + rotate(a[..., 2], b[..., :2])
    return np.concatenate([t, wrap_angle(a[..., 2] + b[..., 2])[..., None]], -1)


def inverse(a):
    """a⁻¹, so that compose(a, inverse(a)) is the identity."""
    a = np.asarray(a, float)
    t = -rotate_inverse(a[..., 2], a[..., :2])
    return np.concatenate([t, wrap_angle(-a[..., 2])[..., None]], -1)


def between(a, b):
    """a ⊖ b = b⁻¹ ∘ a: pose a expressed in the frame of pose b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = rotate_inverse(b[..., 2], a[..., :2] - b[..., :2])
    return np.concatenate([t, wrap_angle(a[..., 2] - b[..., 2])[..., None]], -1)


def transform_points(pose, points):
    """Points (N, 2) given in the frame of ``pose`` expressed in the parent frame."""
    pose = np.asarray(pose, float)
    return rotate(pose[2], np.asarray(points, float)) + pose[:2]


def to_matrix(pose):
    """Homogeneous 3x3 matrix of a single pose."""
    x, y, th = pose
    c, s = np.cos(th), np.sin(th)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def from_matrix(mat):
    """Pose (x, y, θ) of a homogeneous 3x3 (or the planar part of a 4x4) matrix."""
    mat = np.asarray(mat, float)
    if mat.shape == (4, 4):
        return np.array([mat[0, 3], mat[1, 3], np.arctan2(mat[1, 0], mat[0, 0])])
    return np.array([mat[0, 2], mat[1, 2], np.arctan2(mat[1, 0], mat[0, 0])])


def to_matrix4(pose):
    """Homogeneous 4x4 matrix of a planar pose (z = 0), as KISS-ICP wants."""
    m = np.eye(4)
    m[:2, :2] = rotation(pose[2])
    m[:2, 3] = pose[:2]
    return m


# --- Jacobians -------------------------------------------------------------------------
# Poses are perturbed additively, x ⊕ Δ = (x + Δx, y + Δy, wrap(θ + Δθ)), so these are
# plain partial derivatives with respect to (x, y, θ).


def _block(rot, col_theta, d_theta_theta):
    """Assemble (..., 3, 3) Jacobians [[rot, col_theta], [0, 0, d_theta_theta]]."""
    shape = rot.shape[:-2]
    jac = np.zeros(shape + (3, 3))
    jac[..., :2, :2] = rot
    jac[..., :2, 2] = col_theta
    jac[..., 2, 2] = d_theta_theta
    return jac


def compose_with_jacobians(a, b):
    """c = a ⊕ b with ∂c/∂a and ∂c/∂b, each (..., 3, 3)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = compose(a, b)
    rot_a = rotation(a[..., 2])
    # ∂(R(θa) t_b)/∂θa = R(θa) S t_b = S R(θa) t_b, the rotated t_b turned by 90°.
    rotated_tb = rotate(a[..., 2], b[..., :2])
    j_a = _block(np.broadcast_to(np.eye(2), rot_a.shape), rotated_tb @ S.T, 1.0)
    j_b = _block(rot_a, 0.0, 1.0)
    return c, j_a, j_b


def between_with_jacobians(a, b):
    """e = a ⊖ b (= b⁻¹ ∘ a) with ∂e/∂a and ∂e/∂b, each (..., 3, 3)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    e = between(a, b)
    rot_bt = np.swapaxes(rotation(b[..., 2]), -1, -2)
    j_a = _block(rot_bt, 0.0, 1.0)
    # ∂(R(θb)ᵀ(t_a − t_b))/∂θb = −S R(θb)ᵀ(t_a − t_b) = −S e_t.
    j_b = _block(-rot_bt, -(e[..., :2] @ S.T), -1.0)
    return e, j_a, j_b


def chain(motion) -> np.ndarray:
    """Poses from the origin along relative motions: pose_i = pose_{i−1} ⊕ motion_i
    (motion_0 is ignored). A scalar loop: sequential by nature, and numpy's per-call
    overhead on 3-vectors made it a tenth of an online window solve."""
    poses = np.zeros((len(motion), 3))
    x = y = theta = 0.0
    for i, (dx, dy, dtheta) in enumerate(motion.tolist()[1:], start=1):
        c, s = math.cos(theta), math.sin(theta)
        x, y = x + c * dx - s * dy, y + s * dx + c * dy
        theta = math.atan2(math.sin(theta + dtheta), math.cos(theta + dtheta))
        poses[i] = (x, y, theta)
    return poses

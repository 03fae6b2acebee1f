"""Central-difference Jacobians, the reference every analytic Jacobian is tested against."""
import numpy as np


def central_difference(func, x, eps=1e-6):
    x = np.asarray(x, float)
    f0 = np.asarray(func(x), float)
    jac = np.zeros(f0.shape + x.shape)
    for idx in np.ndindex(x.shape):
        step = np.zeros_like(x)
        step[idx] = eps
        diff = np.asarray(func(x + step)) - np.asarray(func(x - step))
        jac[(...,) + idx] = diff / (2 * eps)
    return jac

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


def check_factor_jacobians(factor, values, atol=1e-6):
    """Every Jacobian block of a factor against central differences of its residual.

    Each block is perturbed through its own argument only; the solver sums blocks that
    touch the same variable row.
    """
    lin = factor.linearize(values)
    for jb in lin.blocks:
        for edge, row in enumerate(jb.rows):
            def residual_of(var, edge=edge, row=row, block=jb.block):
                perturbed = values.copy()
                perturbed[block][row] = var
                return factor.linearize(perturbed).residual[edge]

            numeric = central_difference(residual_of, values[jb.block][row])
            assert np.allclose(jb.jacobian[edge], numeric, atol=atol), (factor.name, jb.block)

"""Structure in the residuals: whiteness, dependence on regressors, and which regressor
explains most of what a model leaves.

Residuals are whitened (the stated noise grows with the wheel angle turned, so raw
residuals would correlate with speed through their spread alone) and clipped at
±StructureConfig.residual_clip so that an odd failed scan match cannot dominate. A
residual-regressor dependence counts as structure when its multiple correlation is at
least StructureConfig.min_strength and significant after a Bonferroni correction over
all tests at StructureConfig.alpha.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from sclam_ros.diagnosis.config import StructureConfig


def ljung_box(series, lags: int, first: int = 1):
    """(Q, p) of the Ljung-Box test of no autocorrelation at lags `first` to `lags`, on
    the signs of the series about its median.

    Signs, because a whiteness test must not be decided by one stretch: a few dozen scan
    matches that go wrong together (a featureless stretch, a sharp turn with a narrow
    laser) make large residuals of alternating sign whose products dominate the sample
    autocorrelation of the values, clipped or not, on recordings with no effect at all. A
    missing effect moves the residuals' mean for long stretches and shows in their signs
    as runs. Under the null the signs' autocorrelation has the values' 1/n variance.

    From first = 2 the test allows any correlation at lag 1: Bartlett's variance of the
    sample autocorrelation beyond lag 1 of an MA(1) series, (1 + 2ρ₁²)/n, scales Q."""
    x = np.sign(np.asarray(series, float) - np.median(series))
    x = x - np.mean(x)
    n = len(x)
    lags = min(lags, n // 4)
    denom = float(np.dot(x, x))
    if lags < first or denom <= 0:
        return 0.0, 1.0
    rho = np.array([np.dot(x[:-h], x[h:]) / denom for h in range(1, lags + 1)])
    h = np.arange(first, lags + 1)
    q = n * (n + 2) * np.sum(rho[first - 1:] ** 2 / (n - h))
    if first > 1:
        q /= 1.0 + 2.0 * rho[0] ** 2
    return float(q), float(stats.chi2.sf(q, len(h)))


def explained(x, y):
    """(R², adjusted R², p-value of the F test) of the least-squares fit y ~ 1 + x, x (n, c).
    For one column R² is Pearson's r². (Not a rank correlation: most edges drive straight,
    and ranking their near-zero ω by its noise shows strong "structure" on runs with no
    effect at all; docs/decisions/diagnose.md.)"""
    x = x[:, np.ptp(x, axis=0) > 0]
    n, c = len(y), x.shape[1]
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    if c == 0 or n <= c + 2 or ss_tot <= 0:
        return 0.0, 0.0, 1.0
    design = np.column_stack([np.ones(n), x])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    r2 = float(np.clip(1.0 - np.sum((y - design @ coef) ** 2) / ss_tot, 0.0, 1.0))
    f = (r2 / c) / max((1.0 - r2) / (n - c - 1), 1e-300)
    return r2, 1.0 - (1.0 - r2) * (n - 1) / (n - c - 1), float(stats.f.sf(f, c, n - c - 1))


def fitted_values(x, y, config: StructureConfig):
    """The least-squares combination of the columns of x (n, c) that best predicts y (one
    column: x itself), for plotting a residual against a group of regressors."""
    if x.shape[1] == 1:
        return x[:, 0]
    design = np.column_stack([np.ones(len(y)), x])
    clip = config.residual_clip
    coef, *_ = np.linalg.lstsq(design, np.clip(y, -clip, clip), rcond=None)
    return design[:, 1:] @ coef[1:]


def residual_tests(residuals: dict, regs: dict, edge_of: dict, config: StructureConfig) -> list:
    """Dependence of every residual component on every regressor group, and whiteness.

    residuals: component name -> (m,) whitened values; regs: group name -> (m_o, c);
    edge_of: component name -> (m,) index into the regressor rows. Strength: the multiple
    correlation √R²; whiteness: Ljung-Box from lag config.ljung_box_first_lag to
    config.ljung_box_lags (regressor "lag")."""
    out = []
    for comp, res in residuals.items():
        y = np.clip(res, -config.residual_clip, config.residual_clip)
        for name, reg in regs.items():
            if len(y) < 10:
                continue
            r2, r2_adj, p = explained(reg[edge_of[comp]], y)
            if np.isfinite(r2):
                out.append({"component": comp, "regressor": name, "strength": float(np.sqrt(r2)),
                            "fraction_explained": float(max(r2_adj, 0.0)), "p_value": p})
        q, p = ljung_box(res, config.ljung_box_lags, config.ljung_box_first_lag)
        out.append({"component": comp, "regressor": "lag",
                    "strength": float(np.sqrt(q / max(len(res), 1))), "p_value": p})
    return out


def significant(tests: list, config: StructureConfig) -> list:
    threshold = config.alpha / max(len(tests), 1)
    keep = [t for t in tests if t["p_value"] < threshold
            and (t["regressor"] == "lag" or t["strength"] >= config.min_strength)]
    return sorted(keep, key=lambda t: -t["strength"])


def regressor_shares(residuals: dict, regs: dict, edge_index, motion, config: StructureConfig) -> tuple:
    """({regressor name: the fraction of the odometry's structure it explains}, the
    components with structure): a regressor's fraction is its mean adjusted R² over the
    components with significant structure ({} when none has any).

    residuals: "odometry.x/y/theta" -> (m,) whitened; motion: (m_o, 3) each edge's
    predicted motion. Each regressor f is fitted per component in two forms at once, an
    additive error (∝ f) and a scale error (∝ f times the component's own motion). One
    cause shows in several components: a radius growing with speed scales the whole
    motion by v², which is v³ in x and v²·ω in θ; in additive form alone θ's v²·ω looks
    like v·ω and names the wrong cause."""
    tests, axis = [], {"odometry.x": 0, "odometry.y": 1, "odometry.theta": 2}
    for comp, res in residuals.items():
        own = motion[edge_index, axis[comp]][:, None]
        y = np.clip(res, -config.residual_clip, config.residual_clip)
        for name, reg in regs.items():
            x = reg[edge_index]
            r2, r2_adj, p = explained(np.column_stack([x, x * own]), y)
            tests.append({"component": comp, "regressor": name, "fraction_explained": max(r2_adj, 0.0),
                          "strength": float(np.sqrt(r2)), "p_value": p})
    structured = sorted({t["component"] for t in significant(tests, config)})
    share = {}
    for t in tests:
        if t["component"] in structured:
            share[t["regressor"]] = share.get(t["regressor"], 0.0) + (
                t["fraction_explained"] / len(structured))
    return share, structured


def name_structure(residuals: dict, regs: dict, edge_index, motion, config: StructureConfig,
                   top: int = 3) -> list:
    """The regressors that explain most of the structure left in the odometry, best first
    (regressor_shares), with the components that have structure."""
    share, structured = regressor_shares(residuals, regs, edge_index, motion, config)
    best = sorted(share.items(), key=lambda kv: -kv[1])[:top]
    return [{"regressor": name, "fraction_explained": float(f), "components": structured}
            for name, f in best]

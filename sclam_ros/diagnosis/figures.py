"""Figures of a diagnosis: each residual component against its strongest regressors, before
(base model) and after (extended model) on the same axes."""
from __future__ import annotations

from typing import TYPE_CHECKING

from sclam_ros.diagnosis.structure import fitted_values

if TYPE_CHECKING:
    from sclam_ros.diagnosis.diagnose import Diagnosis


def write_diagnosis_report(out_dir, diagnosis: Diagnosis, per_figure: int = 6) -> list:
    """PNG per residual component: the residual against its strongest regressors, before
    (base model) and after (extended model) on the same axes, clipped as the diagnosis's
    tests clip them (its config)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from pathlib import Path

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    strongest = {}
    for t in sorted(diagnosis.tests_before, key=lambda t: -t["strength"]):
        if t["regressor"] != "lag":
            strongest.setdefault(t["component"], []).append(t)
    for comp, tests in strongest.items():
        tests = tests[:3]
        fig, axes = plt.subplots(1, len(tests), figsize=(4.5 * len(tests), 3.6), squeeze=False)
        idx = diagnosis.edge_of[comp]
        for ax, t in zip(axes[0], tests):
            # A group of columns is drawn against its least-squares combination.
            x = fitted_values(diagnosis.regressors[t["regressor"]][idx],
                              diagnosis.residuals_before[comp], diagnosis.config.structure)
            ax.plot(x, diagnosis.residuals_before[comp], ".", ms=3, alpha=0.6, label="before (base)")
            ax.plot(x, diagnosis.residuals_after[comp], ".", ms=3, alpha=0.6, label="after (extended)")
            ax.set_xlabel(t["regressor"])
            ax.set_ylabel(f"{comp} (whitened)")
            ax.set_title(f"|ρ| = {t['strength']:.2f} before")
            ax.legend(fontsize=7)
        fig.tight_layout()
        path = out / f"residual_{comp.replace('.', '_')}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths

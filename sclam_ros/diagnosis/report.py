"""The diagnosis's JSON report: the base and extended models before and after, each effect
with its evidence, and the warnings.
"""
from __future__ import annotations

from sclam_ros.core import graph as graph_mod
from sclam_ros.core.estimator import residual_rms
from sclam_ros.diagnosis.config import SelectionConfig
from sclam_ros.diagnosis.effects import LIBRARY
from sclam_ros.diagnosis.evidence import standard_error

ERROR_METRIC = (
    "held-out mean negative log-likelihood per edge (nats, constant dropped) of the "
    "laser-vs-odometry disagreement d = (l⁻¹ ∘ K(u; k, effects) ∘ l) ⊖ z of the edges of "
    "each held-out time block ({folds}-fold contiguous-block cross-validation, calibration "
    "and effects fitted on the other blocks; a noise effect's evidence: {noise_folds} "
    "folds of {spread} blocks each, spread over the run): 0.5·(ρ(dᵀΣ⁻¹d) + ln det Σ), Σ the fitted "
    "odometry + scan-match covariance in the laser frame, ρ the graph's Cauchy kernel (c = {c:g})"
)


def error_metric(selection: SelectionConfig) -> str:
    """The report's description of its error (`error_metric`)."""
    return ERROR_METRIC.format(folds=selection.folds, noise_folds=selection.noise_folds,
                               spread=selection.noise_fold_blocks, c=graph_mod.laser_kernel().c)


def effect_json(ev: dict, selected_names) -> dict:
    gain = ev["gain"]
    selected = ev["name"] in selected_names
    # What fit about as well as a selected effect, and was not selected itself.
    alternatives = [a for a in ev.get("alternatives", []) if a not in selected_names] if selected else []
    return {
        "name": ev["name"], "selected": selected, "value": ev["value"], "sigma": ev["sigma"],
        "evidence": {
            "heldout_error": ev["heldout_error"], "heldout_error_base": ev["heldout_error_base"],
            "heldout_folds": ev["heldout_folds"],
            "heldout_gain_per_edge": float(gain.mean()),
            "heldout_gain_stderr": standard_error(gain),
            "likelihood_ratio": ev["lr"], "bic_penalty": ev["bic"],
            "heldout_likelihood_ratio": ev["heldout_lr"],
            **({"heldout_penalty": ev["heldout_penalty"]}
               if ev["heldout_penalty"] is not None else {}),
            "added_to": ev["added_to"],
            "units": LIBRARY[ev["name"]].units,
            "identifiability": ev["identifiability"],
            **({"blocked_by_mean_structure": ev["blocked_by_mean_structure"]}
               if ev["blocked_by_mean_structure"] else {}),
            **({"stand_in_for": ev["stand_in_for"]} if ev["stand_in_for"] else {}),
            **({"alternatives": alternatives} if alternatives else {}),
            **({"params": ev["params"]} if ev["params"] is not None else {}),
        },
        **ev["describe"],
    }


def effects_json(names, evidence: dict, selected, final: dict) -> list:
    """Every candidate's entry, in the order tried; the selected ones with the value and σ
    of the final fit of all of them together (`final`: name -> (value, σ, ...))."""
    out = []
    for name in names:
        e = effect_json(evidence[name], selected)
        if name in final:
            e["value"], e["sigma"] = final[name][:2]
        out.append(e)
    return out


def model_summary(fit, error) -> dict:
    """A model's calibration, residual RMS and held-out error."""
    rms = residual_rms(fit.problem, fit.values)
    return {
        "params": graph_mod.as_dict(graph_mod.calibration_of(fit.values)),
        "residual_rms": {k: [float(x) for x in v] for k, v in rms.items()
                         if k in ("odometry", "laser")},
        "error": error,
    }


def warnings(selected, shift: dict, pairs: list, max_shift_sigma: float) -> list:
    """The calibration moved by more than `max_shift_sigma` by the selected effects, and
    the pairs of effects the recording cannot tell apart."""
    out = [f"adding {', '.join(selected)} moved {k} by {z:+.1f} σ (of the extended model)"
           for k, z in shift.items() if abs(z) > max_shift_sigma]
    out += [f"{p['effects'][0]} and {p['effects'][1]} cannot be told apart on this "
            f"recording (correlation {p['correlation']:.2f}); selected: "
            f"{', '.join(p['selected']) or 'neither'}" for p in pairs]
    return out

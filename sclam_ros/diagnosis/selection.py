"""Stepwise selection of library effects, each judged by evidence.evaluate on top of the
ones already selected: of several that pass in a round, mean effects before noise effects
and the simplest within one standard error of the best joins; an earlier one that no
longer passes on top of the others leaves; an effect that has the evidence but cannot be
told apart from selected ones may replace them.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.diagnosis.cross_validation import Models
from sclam_ros.diagnosis.effects import LIBRARY
from sclam_ros.diagnosis.evidence import evaluate


def stepwise_selection(models: Models, names, n_edges, say):
    """Stepwise selection. Each round, every remaining effect is fitted on top of the ones
    selected so far, and one of those that pass (held-out gain > its standard error, likelihood ratio >
    BIC penalty, determined together with the selected ones) joins: the simplest of those
    whose held-out error is within one standard error of the best's (the one-standard-
    error rule). Then each earlier selected effect is tried on top of the others, and
    leaves for good if it no longer passes. Trying effects on top of the selected ones,
    not only against the base model, lets an effect whose signature is buried under a
    larger one show, and keeps one that only re-explains a selected one out.

    When none passes, an effect that has the evidence but cannot be told apart from
    selected ones (identifiability) may replace them, if the model with it instead has
    the lower held-out error: a clock offset selected first gives way to a sweep's
    delay with its turn-rate shift, never both. Every pair of a candidate and a selected
    effect that the recording cannot separate is returned, whether or not the candidate
    had the evidence.

    Returns the selected names, per effect the evidence of the last time it was tried,
    and the pairs the recording cannot separate.
    """
    max_correlation = models.config.identifiability.max_correlation
    selected, evidence, pairs = [], {}, []
    remaining = list(names)
    while remaining:
        say("trying " + ", ".join(remaining) + (" on top of " + ", ".join(selected)
                                                 if selected else ""))
        round_ = {n: evaluate(models, selected, n, n_edges) for n in remaining}
        evidence.update(round_)
        pairs += [{"effects": sorted([n, other]),
                   "correlation": round_[n]["identifiability"]["correlations"][other]}
                  for n in remaining for other in _entangled(round_[n], max_correlation)]
        passing = [n for n in remaining if round_[n]["passes"]]
        if passing:
            chosen, near = _simplest_near_best(models, selected, passing, round_)
            # What else the data fit about as well: the choice among them is the simplest,
            # not what the recording showed, and the report says so.
            evidence[chosen] = {**round_[chosen], "alternatives": [n for n in near if n != chosen]}
            selected.append(chosen)
            remaining.remove(chosen)
        else:
            swap = _best_swap(models, selected, remaining, round_, n_edges)
            if swap is None:
                break
            chosen, replaced, ev = swap
            say(f"{chosen} replaces {', '.join(replaced)}: not separable, lower held-out error")
            evidence[chosen] = ev
            selected = [n for n in selected if n not in replaced] + [chosen]
            remaining.remove(chosen)
        for earlier in selected[:-1]:
            others = [n for n in selected if n != earlier]
            again = evaluate(models, others, earlier, n_edges)
            if not again["passes"]:
                say(f"dropping {earlier}: no longer adds to " + ", ".join(others))
                evidence[earlier] = again
                selected.remove(earlier)
    return selected, evidence, _unique_pairs(pairs, selected)


def _entangled(ev, max_correlation) -> list:
    """The selected effects an evaluated candidate cannot be told apart from."""
    return [n for n, c in ev["identifiability"]["correlations"].items() if c > max_correlation]


def _best_swap(models: Models, selected, remaining, round_, n_edges):
    """(candidate, the selected effects it replaces, its evidence) of the best replacement
    among candidates that have the evidence but not the identifiability, or None."""
    best = None
    for name in remaining:
        ev = round_[name]
        tangled = _entangled(ev, models.config.identifiability.max_correlation)
        if not ev["evidence_passes"] or not tangled:
            continue
        spread = LIBRARY[name].kind == "noise"
        current = float(np.mean(models.heldout_nll(selected, spread)))
        others = [n for n in selected if n not in tangled]
        again = evaluate(models, others, name, n_edges)
        error = float(np.mean(models.heldout_nll(others + [name], spread)))
        if again["passes"] and error < current and (best is None or error < best[3]):
            best = (name, tangled, again, error)
    return None if best is None else best[:3]


def _unique_pairs(pairs, selected) -> list:
    out = {}
    for p in pairs:
        key = tuple(p["effects"])
        if key not in out or p["correlation"] > out[key]["correlation"]:
            out[key] = {**p, "selected": [n for n in key if n in selected]}
    return list(out.values())


def _simplest_near_best(models: Models, selected, passing, round_):
    """(chosen, the candidates within one standard error of the best): mean effects before
    noise effects (a variance model over a mean misfit takes the misfit for noise, and the
    two kinds are judged on different folds), then the simplest within one standard error
    of the best."""
    passing = [n for n in passing if LIBRARY[n].kind != "noise"] or passing
    spread = LIBRARY[passing[0]].kind == "noise"
    best = max(passing, key=lambda n: round_[n]["gain"].mean())
    best_nll = models.heldout_nll(selected + [best], spread)

    def near(name):
        worse = models.heldout_nll(selected + [name], spread) - best_nll
        return worse.mean() <= worse.std(ddof=1) / np.sqrt(len(worse))

    close = [n for n in passing if near(n)]
    return min(close, key=lambda n: (models.effects([n])[0].dim, -round_[n]["gain"].mean())), close

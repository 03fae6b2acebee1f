"""Each robot's calibrations over time, and the changes the σ cannot explain.

Two successive calibrations of one robot are compared parameter by parameter: a difference
larger than CHANGE_SIGMAS combined σ (sqrt(σ₁² + σ₂²)) is flagged as a change of the robot
(a worn or replaced tyre, a knocked laser), not noise. Parameters not observable in either
recording are not compared: they hold their nominal value there, not a measurement.
"""
from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from sclam_ros.core.params import CALIBRATION_KEYS

CHANGE_SIGMAS = 3.0  # a false alarm per parameter pair at about 0.3 % if σ is honest


@dataclass
class Change:
    robot: str
    parameter: str
    bag_before: str
    bag_after: str
    before: float
    after: float
    sigmas: float  # |after − before| / combined σ


def by_robot(results: list[dict]) -> dict[str, list[dict]]:
    """robot → its successful calibrations in start-time order."""
    robots = defaultdict(list)
    for result in results:
        if result["status"] == "ok":
            robots[result["robot"]].append(result)
    for series in robots.values():
        series.sort(key=lambda r: (r.get("start_time") or 0.0, r["bag"]))
    return dict(sorted(robots.items()))


def changes(results: list[dict], threshold: float = CHANGE_SIGMAS) -> list[Change]:
    found = []
    for robot, series in by_robot(results).items():
        for before, after in zip(series, series[1:]):
            for key in CALIBRATION_KEYS:
                if not (before["observable"][key] and after["observable"][key]):
                    continue
                combined = math.hypot(before["sigma"][key], after["sigma"][key])
                z = abs(after["estimate"][key] - before["estimate"][key]) / combined
                if z > threshold:
                    found.append(Change(robot, key, before["bag"], after["bag"],
                                        before["estimate"][key], after["estimate"][key], z))
    return found


def human(key: str, value: float) -> float:
    """mm for lengths, degrees for the yaw."""
    return math.degrees(value) if key == "laser_yaw" else 1000.0 * value


def recording_name(bag: str) -> str:
    return Path(bag).name


def format_history(results: list[dict], found: list[Change]) -> str:
    """Per robot, one line per calibration: value ± σ of every parameter (mm, deg)."""
    flagged = {(c.bag_after, c.parameter) for c in found}
    header = f"{'recording':<24}" + "".join(
        f"{k + (' deg' if k == 'laser_yaw' else ' mm'):>24}" for k in CALIBRATION_KEYS)
    lines = []
    for robot, series in by_robot(results).items():
        lines += [f"robot {robot}", header]
        for result in series:
            cells = []
            for key in CALIBRATION_KEYS:
                if not result["observable"][key]:
                    cells.append(f"{'(not observed)':>24}")
                    continue
                mark = " !" if (result["bag"], key) in flagged else "  "
                cells.append(f"{human(key, result['estimate'][key]):>12.3f} ±"
                             f"{human(key, result['sigma'][key]):>7.3f}{mark}")
            lines.append(f"{recording_name(result['bag'])[:24]:<24}" + "".join(cells))
        lines.append("")
    if found:
        lines.append(f"changes beyond {CHANGE_SIGMAS:g} combined σ (marked ! above):")
        for c in found:
            lines.append(f"  {c.robot}: {c.parameter} {human(c.parameter, c.before):.3f} → "
                         f"{human(c.parameter, c.after):.3f} ({c.sigmas:.1f} σ) between "
                         f"{recording_name(c.bag_before)} and {recording_name(c.bag_after)}")
    else:
        lines.append(f"no change beyond {CHANGE_SIGMAS:g} combined σ between successive calibrations")
    return "\n".join(lines)


def plot_history(results: list[dict], found: list[Change], path) -> None:
    """One panel per parameter: each robot's estimates ±1σ in recording order, changes in red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    robots = by_robot(results)
    flagged = {(c.bag_after, c.parameter) for c in found}
    fig, axes = plt.subplots(len(CALIBRATION_KEYS), 1, figsize=(9, 2.1 * len(CALIBRATION_KEYS)),
                             sharex=True)
    for ax, key in zip(axes, CALIBRATION_KEYS):
        for number, (robot, series) in enumerate(robots.items()):
            # Recording order, not time: start times of simulated or re-stamped bags repeat.
            xs = [i for i, r in enumerate(series) if r["observable"][key]]
            ys = [human(key, series[i]["estimate"][key]) for i in xs]
            es = [human(key, series[i]["sigma"][key]) for i in xs]
            ax.errorbar(xs, ys, yerr=es, marker="o", ms=3, capsize=2, label=robot,
                        color=f"C{number % 10}")
            bad = [(x, y) for x, y in zip(xs, ys) if (series[x]["bag"], key) in flagged]
            if bad:
                ax.plot(*zip(*bad), "o", ms=10, mfc="none", mec="red", mew=1.5)
        ax.set_ylabel(f"{key}\n[{'deg' if key == 'laser_yaw' else 'mm'}]", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("calibration number of the robot (in start-time order)")
    axes[-1].xaxis.get_major_locator().set_params(integer=True)
    axes[0].legend(fontsize=7, ncol=4, loc="best")
    axes[0].set_title("calibration history (±1σ); red circles: change beyond "
                      f"{CHANGE_SIGMAS:g} combined σ")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

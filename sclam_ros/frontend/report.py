"""What the front end did with its input, copied out of it: the matches it made and
confirmed, what it did not use and why, and how it judged the laser. `sclam calibrate`
prints it, the node's /diagnostics show it (online.estimate.CalibratorStatus), the benches
quote it; none of them reads the front end's parts."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Optional


@dataclass(frozen=True)
class FrontendReport:
    # --- scan matches ---------------------------------------------------------------------
    matches: int  # KISS-ICP gave, used or not
    # reason -> matches not used: the point-to-line refinement could not confirm them
    # (point_to_line.RefinedScanMatcher.unrefined)
    unconfirmed: dict
    # Scans registered from the previous scan's motion after the wheel odometry's
    # prediction failed / was overlapped better by it (scan_matching.ScanMatcher).
    odometry_guess_failures: int
    odometry_guess_overruled: int
    # --- scans not matched by design (decimation.py) --------------------------------------
    skipped_scans: int
    match_every: Optional[int]  # 1 scan in n is matched (None until the rate is known)
    match_period: float  # s, about this far apart
    matches_follow_samples: bool  # also the scan after each encoder sample (slow encoders)
    # --- the laser's range noise, judged on its first scans (laser_noise.py) --------------
    noisy_laser: bool  # its wall lines are fitted to whole straight segments
    range_noise: float  # m, the median measured (NaN before the first scan judged)
    range_noise_growth: float  # 1/m of its value at 0 m, 0 where it does not grow
    noisy_from: float  # m, the range noise from which a laser is judged noisy (config)
    line_beams: int  # beams a wall line is fitted to on a quiet laser (config)

    @property
    def confirmed(self) -> int:
        """Matches the refinement confirmed (used)."""
        return self.matches - sum(self.unconfirmed.values())

    @property
    def mostly_unconfirmed(self) -> bool:
        """More than half of the matches could not be confirmed (few straight surfaces)."""
        return 2 * self.confirmed < self.matches

    @property
    def sigma_may_be_small(self) -> bool:
        """A noisy laser with most matches unconfirmed: on the simulator's outdoor scene
        the errors are then larger than their σ says (docs/accuracy.md)."""
        return self.noisy_laser and self.mostly_unconfirmed

    def since(self, earlier: "FrontendReport") -> "FrontendReport":
        """This report's counts less those of an earlier report of the same front end."""
        unconfirmed = {reason: n - earlier.unconfirmed.get(reason, 0)
                       for reason, n in self.unconfirmed.items()}
        return dataclasses.replace(
            self, matches=self.matches - earlier.matches,
            unconfirmed={reason: n for reason, n in unconfirmed.items() if n},
            odometry_guess_failures=self.odometry_guess_failures - earlier.odometry_guess_failures,
            odometry_guess_overruled=(self.odometry_guess_overruled
                                      - earlier.odometry_guess_overruled),
            skipped_scans=self.skipped_scans - earlier.skipped_scans)

    @classmethod
    def of(cls, frontend) -> "FrontendReport":
        """The report of a pipeline.Frontend so far."""
        refined, decimator = frontend.refined_matcher, frontend.decimator
        laser_noise, config = refined.laser_noise, refined.config
        return cls(
            matches=refined.matches, unconfirmed=dict(refined.unrefined),
            odometry_guess_failures=frontend.matcher.odometry_guess_failures,
            odometry_guess_overruled=frontend.matcher.odometry_guess_overruled,
            skipped_scans=decimator.skipped, match_every=decimator.every,
            match_period=decimator.match_period,
            matches_follow_samples=decimator.follows_samples,
            noisy_laser=laser_noise.noisy, range_noise=laser_noise.median,
            range_noise_growth=laser_noise.growth,
            noisy_from=config.laser_noise.noisy_range,
            line_beams=config.reference_lines.normal_neighbours,
        )

"""When a demonstration's hand takes its final orientation, measured from when it arrives.

A demonstrator who pours moves the cup to the goal and then tilts it: the position arrives
first, the orientation later. A primitive that imitates the demonstrations does the same, so a
success criterion that asks for the goal orientation a fixed time after the hand first enters
the goal ball (Table 1's *with orientation*: 0.2 rad, 2 s after the reach) judges the
demonstrations' timing as much as the controller. These functions read that timing off the
prepared demonstrations (:class:`~tamedpuma.puma.data.Demonstrations`: positions
``e = p − p_end`` [m, or the data's unit] and orientations ``ζ ⊗ ζ_end⁻¹`` relative to each
one's final pose, on a grid of Δt [s]):

- ``arrival_i`` = the first time ``‖e_i(t)‖ ≤ radius``;
- ``turned_i`` = the first time after which the angle ``2 atan2(‖ζ_xyz‖, |ζ_w|)`` of ζ_i stays
  ``≤ angle`` to the end;
- the lag ``turned_i − arrival_i`` [s] (0 where the orientation is there first), and whether the
  angle is within ``angle`` at ``arrival_i + settle`` (the demonstration's own verdict under the
  criterion; its end, on the goal pose, where it ends sooner).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..puma.data import Demonstrations
from ..robot.rotations import quat_angle


@dataclass(frozen=True)
class OrientationTiming:
    """Per demonstration: the arrival in the ball [s], the lag of the orientation after it [s],
    and whether the orientation is within the angle ``settle`` [s] after the arrival."""

    arrival_s: np.ndarray
    lag_s: np.ndarray
    held_after_settle: np.ndarray

    def as_dict(self) -> dict:
        """Medians, maxima and the held fraction (one row of the table :func:`main` prints)."""
        return {"arrival_s_median": float(np.median(self.arrival_s)),
                "lag_s_median": float(np.median(self.lag_s)),
                "lag_s_max": float(np.max(self.lag_s)),
                "held_after_settle": float(np.mean(self.held_after_settle))}


def orientation_timing(demos: Demonstrations, radius: float = 0.05, angle: float = 0.2,
                       settle: float = 2.0) -> OrientationTiming | None:
    """:class:`OrientationTiming` of every demonstration (None without orientations): ball
    ``radius`` [data unit], ``angle`` [rad], ``settle`` [s] (see the module)."""
    if demos.quat is None:
        return None
    arrival, lag, held = [], [], []
    for pos, quat in zip(demos.pos, demos.quat):
        t = np.arange(len(pos)) * demos.dt
        inside = np.linalg.norm(pos, axis=1) <= radius
        k = int(np.argmax(inside)) if inside.any() else len(pos) - 1
        off = quat_angle(quat) > angle
        turned = t[int(np.nonzero(off)[0][-1]) + 1] if off.any() else 0.0
        j = min(len(t) - 1, int(np.searchsorted(t, t[k] + settle - 1e-9)))
        arrival.append(t[k])
        lag.append(max(0.0, turned - t[k]))
        held.append(not off[j])
    return OrientationTiming(np.array(arrival), np.array(lag), np.array(held))


def timing_rows(folders: list[str], dt: float = 0.03, smoothing: float = 2.0,
                radius: float = 0.05, angle: float = 0.2, settle: float = 2.0) -> list[dict]:
    """One row per demonstration folder (any format :func:`~tamedpuma.puma.demo_formats.load_any`
    reads), its demonstrations prepared as the default training prepares them (Δt ``dt`` [s],
    ``smoothing`` [samples])."""
    from ..puma import data, demo_formats

    rows = []
    for folder in folders:
        demos = data.prepare(demo_formats.load_any(folder), dt, smoothing=smoothing)
        timing = orientation_timing(demos, radius, angle, settle)
        row = {"demonstrations": str(folder), "n": len(demos)}
        rows.append({**row, **(timing.as_dict() if timing else {})})
    return rows


def main(argv: list[str] | None = None) -> int:
    """``python -m tamedpuma.analysis.demo_timing DIR [DIR ...]``: a markdown table of the
    demonstrations' orientation timing (the criterion's radius, angle and settle time)."""
    import argparse

    from ..errors import TamedPumaError

    parser = argparse.ArgumentParser(prog="python -m tamedpuma.analysis.demo_timing",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", help="demonstration folders")
    parser.add_argument("--radius", type=float, default=0.05, help="goal ball [m] (0.05)")
    parser.add_argument("--angle", type=float, default=0.2, help="orientation tolerance "
                        "[rad] (0.2)")
    parser.add_argument("--settle", type=float, default=2.0, help="time after the arrival "
                        "[s] (2)")
    args = parser.parse_args(argv)
    try:
        rows = timing_rows(args.folders, radius=args.radius, angle=args.angle,
                           settle=args.settle)
    except (TamedPumaError, OSError) as exc:
        print(f"error: {exc}")
        return 2
    print("| demonstrations | n | arrival in the ball [s] (median) | orientation after it [s] "
          f"(median / max) | within {args.angle} rad {args.settle:g} s after the arrival |")
    print("|---|---|---|---|---|")
    for r in rows:
        if "lag_s_median" not in r:
            print(f"| {r['demonstrations']} | {r['n']} | — | no orientations | — |")
            continue
        print(f"| {r['demonstrations']} | {r['n']} | {r['arrival_s_median']:.1f} | "
              f"{r['lag_s_median']:.1f} / {r['lag_s_max']:.1f} | "
              f"{r['held_after_settle']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Gates on a trained primitive's evaluation: does it reproduce what it was shown?

The demonstrations' own spread sets the scale: ``s_i`` = DTW per point between demonstration i
and its nearest other demonstration (positions relative to each one's final pose, paths resampled
to at most ``max_points`` samples) [unit of the data]. With one demonstration, ``s_0`` = 0.1 × its
largest distance to the goal. The gates (thresholds in :class:`~.settings.EvalConfig`, 0 = off):

- imitation: mean DTW ≤ max(``gate_spread`` × median s_i, ½ ``gate_extent`` × median e_i, floor);
- worst demonstration: DTW_i ≤ max(``gate_worst`` × s_i, ``gate_extent`` × e_i, floor) for every
  i (a demonstration the network cannot follow from its own start: another goal, a truncated or
  paused motion, or a route that contradicts a neighbour starting close by);
- convergence: converged fraction of the random starts ≥ ``gate_converged``;
- ψ-compatibility: compatible fraction ≥ ``gate_compat``;

with e_i the largest distance of demonstration i from its goal (for nearly coinciding
demonstrations the spread alone is no scale) and floor = ``gate_floor`` × ``pos_tol``
(differences below it are within the convergence tolerance). Each failed gate is one line
naming the demonstration(s) and what to try.

A demonstration that fails the worst-demonstration gate because the data contradicts itself is
told apart from one the network has not learnt yet (:func:`followed_routes`): the rollout from
its start is closer (DTW per point) to another demonstration's route than to its own, and the two
routes lie on average more than :data:`CONFLICT_RATIO` × their start gap apart. A smooth field
carries two starts along at about their distance (a trained pouring model keeps 99 % of rollout
pairs within 1.2× their start gap, all within 1.7×), so routes that part by more than twice their
start gap ask it to take both; it takes one of them or their middle. Routes that part by less are
the learner's to follow. (The routes' largest separation is no test: it is never below the
start gap.) Those are the ``conflicting_demos`` line (the
data's cause: remove one, or record demonstrations between them), the others stay in
``worst_demo`` (the learner's: train longer or wider).

A first-order model (velocity from position alone) is judged against what a first-order field
can do with the data (:mod:`tamedpuma.puma.data_field`, smooth at h = ``gate_floor`` ×
``pos_tol``): a failing demonstration that this field fails to follow too is the
``first_order_data`` line (demonstrations that pass within millimetres of each other with
different velocities: a second-order model follows them), and the imitation line says where
the field's own mean is above the gate.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import TamedPumaError
from .data import Demonstrations
from .data_field import first_order_dtw
from .evaluation import dtw_per_point, dtw_per_point_batch, rollout_paths
from .settings import EvalConfig


class GateError(TamedPumaError):
    """A model refused because it failed a gate (``puma.train.strict=true``)."""


@dataclass(frozen=True)
class Failure:
    """One failed gate: its name, the demonstrations it concerns and the line to print."""

    gate: str
    demos: tuple[str, ...]
    line: str


def _resampled(p: np.ndarray, max_points: int) -> np.ndarray:
    idx = np.unique(np.linspace(0, len(p) - 1, min(len(p), max_points)).round().astype(int))
    return p[idx]


#: two routes conflict when their mean separation (DTW per point) exceeds this × their start gap
CONFLICT_RATIO = 2.0


@dataclass(frozen=True)
class Follow:
    """The rollout from demonstration i's start follows demonstration ``other``'s route."""

    other: int
    to_other: float  # DTW/point of the rollout to ``other``'s route [unit]
    to_own: float    # ... and to its own [unit]
    start_gap: float  # distance between the two starts [unit]
    route_gap: float  # the two routes' mean separation (DTW per point) [unit]


def followed_routes(paths: list[np.ndarray], demos: Demonstrations,
                    max_points: int = 120) -> dict[int, Follow]:
    """The demonstrations i whose rollout ``paths[i]`` (positions from its start, its length)
    is at least as close (DTW/point) to another demonstration j's route as to its own, where
    the two routes lie on average more than :data:`CONFLICT_RATIO` × their start gap apart (so
    no smooth field takes both): i → j.
    Paths and routes are resampled to at most ``max_points`` samples."""
    refs = [_resampled(demos.trimmed(i)[0], max_points) for i in range(len(demos))]
    out = {}
    if len(refs) < 2:
        return out
    for i, path in enumerate(paths):
        d = dtw_per_point_batch([_resampled(np.asarray(path, float), max_points)] * len(refs),
                                refs)
        others = np.delete(np.arange(len(refs)), i)
        j = int(others[np.argmin(d[others])])
        gap = float(np.linalg.norm(refs[i][0] - refs[j][0]))
        if d[j] <= d[i] and CONFLICT_RATIO * gap < (route := dtw_per_point(refs[i], refs[j])):
            out[i] = Follow(j, float(d[j]), float(d[i]), gap, float(route))
    return out


def routes_followed_by(net, demos: Demonstrations) -> dict[int, Follow]:
    """:func:`followed_routes` of the network's rollouts from each demonstration's start."""
    trimmed = [demos.trimmed(i) for i in range(len(demos))]
    pos, _ = rollout_paths(net, np.stack([p[0] for p, _ in trimmed]),
                           np.stack([q[0] for _, q in trimmed]) if demos.orientation else None,
                           max(len(p) for p, _ in trimmed) - 1, demos.dt)
    return followed_routes([pos[i, : len(p)] for i, (p, _) in enumerate(trimmed)], demos)


def demo_spread(demos: Demonstrations, max_points: int = 120) -> np.ndarray:
    """``s_i``: DTW per point [unit] from each demonstration to its nearest other one."""
    return nearest_demos(demos, max_points)[0]


def nearest_demos(demos: Demonstrations, max_points: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """(``s_i``, index of the nearest other demonstration, -1 with a single one)."""
    paths = [_resampled(demos.trimmed(i)[0], max_points) for i in range(len(demos))]
    if len(paths) == 1:
        return np.array([0.1 * float(np.linalg.norm(paths[0], axis=1).max())]), np.array([-1])
    spread, nearest = np.empty(len(paths)), np.empty(len(paths), int)
    for i, ref in enumerate(paths):
        others = [j for j in range(len(paths)) if j != i]
        d = dtw_per_point_batch([paths[j] for j in others], [ref] * len(others))
        spread[i], nearest[i] = float(np.min(d)), others[int(np.argmin(d))]
    return spread, nearest


def demo_names(demos: Demonstrations) -> list[str]:
    """Each demonstration's name (its file, or ``#i``)."""
    names = list(demos.names or ())
    return names if len(names) == len(demos) else [f"#{i}" for i in range(len(demos))]


def _fmt(x: float, unit: str) -> str:
    return f"{100 * x:.2f} cm" if unit == "m" else f"{x:.3g} {unit}"


def _listed(names, values, limits, unit: str, near=None, most: int = 5) -> str:
    order = np.argsort(-np.asarray(values) / np.maximum(np.asarray(limits), 1e-12))
    shown = [f"{names[k]} ({_fmt(values[k], unit)} > {_fmt(limits[k], unit)}"
             + (f", nearest {near[k]}" if near is not None and near[k] else "") + ")"
             for k in order[:most]]
    more = len(order) - most
    return ", ".join(shown) + (f" and {more} more" if more > 0 else "")


def demo_extent(demos: Demonstrations) -> np.ndarray:
    """``e_i``: each demonstration's largest distance from its goal [unit]."""
    return np.array([float(np.linalg.norm(demos.trimmed(i)[0], axis=1).max())
                     for i in range(len(demos))])


def _conflicts(follows: dict, bad, dtw, names, unit: str) -> Failure:
    """The line of the failing demonstrations whose rollout follows another's route."""
    shown = [f"{names[i]} follows {names[follows[i].other]} (starts "
             f"{_fmt(follows[i].start_gap, unit)} apart, routes "
             f"{_fmt(follows[i].route_gap, unit)} apart on average; "
             f"{_fmt(follows[i].to_other, unit)} to its route, "
             f"{_fmt(follows[i].to_own, unit)} to its own)" for i in bad[:5]]
    rest = np.setdiff1d(np.arange(len(dtw)), bad)
    pairs = tuple(dict.fromkeys(n for i in bad for n in (names[i], names[follows[i].other])))
    return Failure("conflicting_demos", pairs, (
        f"{len(bad)} demonstration(s) not reproduced because the data contradicts itself: the "
        "rollout from each one's start takes another demonstration's route, "
        + ", ".join(shown) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        + "; a field cannot take two routes from nearly one start: remove one of each pair or "
        "record demonstrations between their starts (mean DTW/point of the other "
        f"{len(rest)}: {_fmt(float(np.mean(dtw[rest])) if len(rest) else 0.0, unit)})"))


def imitation_limit(spread, extent, cfg: EvalConfig) -> float:
    """The imitation gate's largest mean DTW/point [unit]: max(``gate_spread`` × median s_i,
    ½ ``gate_extent`` × median e_i, ``gate_floor`` × ``pos_tol``)."""
    return max(cfg.gate_spread * float(np.median(spread)),
               0.5 * cfg.gate_extent * float(np.median(extent)), cfg.gate_floor * cfg.pos_tol)


def field_bandwidth(cfg: EvalConfig) -> float:
    """h [unit] of the first-order field the gates compare a first-order model with:
    ``gate_floor`` × ``pos_tol`` (differences below it are within the convergence tolerance)."""
    return cfg.gate_floor * cfg.pos_tol


def first_order_field(demos: Demonstrations, order: int, cfg: EvalConfig) -> np.ndarray | None:
    """For a first-order model (``order`` 1): the DTW/point [unit] per demonstration of the
    data's own first-order field at :func:`field_bandwidth` (:func:`~.data_field.first_order_dtw`),
    which :func:`check` takes as ``field``; None for a second-order model."""
    return None if order != 1 else first_order_dtw(demos, field_bandwidth(cfg))


def _first_order_data(bad, field, limits, names, unit: str, bandwidth: float
                      ) -> tuple[list[Failure], np.ndarray]:
    """(the ``first_order_data`` failure of the demonstrations in ``bad`` that the data's own
    first-order field ``field`` (DTW/point per demonstration, :mod:`.data_field`) misses too,
    the rest of ``bad``)."""
    if field is None or not len(bad):
        return [], bad
    data = np.array([k for k in bad if field[k] > limits[k]], int)
    if not len(data):
        return [], bad
    shown = _listed([names[k] for k in data], field[data], limits[data], unit)
    return [Failure("first_order_data", tuple(names[k] for k in data), (
        f"{len(data)} demonstration(s) no first-order field follows: the field of the "
        f"demonstrations' own velocities, smooth at {_fmt(bandwidth, unit)}, misses them "
        f"too ({shown}); they pass within millimetres of other "
        "demonstrations with other velocities, which a velocity commanded from the position "
        "alone cannot take both of: train a second-order model (puma.order=2), or remove the "
        "crossing demonstrations"))], np.setdiff1d(bad, data)


def _imitation(im: dict, spread, names, cfg: EvalConfig, unit: str, nearest=None,
               extent=None, follows=None, field=None) -> list[Failure]:
    extent = np.zeros_like(spread) if extent is None else np.asarray(extent, float)
    floor = cfg.gate_floor * cfg.pos_tol
    dtw = np.asarray(im.get("dtw_per_demo", [im["dtw"]]), float)
    out = []
    if cfg.gate_worst > 0 and len(dtw) == len(spread):
        limits = np.maximum(np.maximum(cfg.gate_worst * spread, cfg.gate_extent * extent),
                            floor)
        bad = np.flatnonzero(dtw > limits)
        data = np.array([k for k in bad if k in (follows or {})], int)
        if len(data):
            out.append(_conflicts(follows, data, dtw, names, unit))
            bad = np.setdiff1d(bad, data)
        first_order, bad = _first_order_data(bad, field, limits, names, unit,
                                              field_bandwidth(cfg))
        out += first_order
        if len(bad):
            out.append(Failure("worst_demo", tuple(names[k] for k in bad), (
                f"{len(bad)} of {len(dtw)} demonstration(s) not reproduced (DTW/point > "
                f"{cfg.gate_worst:g} x the distance to the nearest other demonstration and "
                f"{cfg.gate_extent:g} x its extent): "
                + _listed([names[k] for k in bad], dtw[bad], limits[bad], unit,
                          None if nearest is None else
                          [names[j] if j >= 0 else "" for j in np.asarray(nearest)[bad]])
                + "; check them for another goal, a truncated or paused motion or a route that "
                "contradicts a neighbour from a close start (remove or re-record them), else "
                "train longer (puma.train.iterations, puma.train.patience)")))
    if cfg.gate_spread > 0:
        limit = imitation_limit(spread, extent, cfg)
        if im["dtw"] > limit:
            worst = np.argsort(-dtw)[:3] if len(dtw) == len(names) else []
            out.append(Failure("imitation", tuple(names[k] for k in worst), (
                f"mean DTW/point {_fmt(im['dtw'], unit)} > {cfg.gate_spread:g} x the "
                f"demonstrations' own spread ({_fmt(float(np.median(spread)), unit)}) = "
                f"{_fmt(limit, unit)}; worst: "
                + ", ".join(f"{names[k]} ({_fmt(dtw[k], unit)})" for k in worst)
                + (f"; a first-order field of the demonstrations' own velocities reaches "
                   f"{_fmt(float(np.mean(field)), unit)}: the data asks for a second-order "
                   "model (puma.order=2)" if field is not None and np.mean(field) > limit else
                   "; try a longer schedule (puma.train.iterations, puma.train.patience; a "
                   "wider network learnt slower per iteration on pouring_v2)"))))
    return out


def check(evaluation: dict, spread: np.ndarray, names: list[str], cfg: EvalConfig,
          unit: str = "m", nearest: np.ndarray | None = None,
          extent: np.ndarray | None = None,
          follows: dict[int, Follow] | None = None,
          field: np.ndarray | None = None) -> list[Failure]:
    """The failed gates of one evaluation (``evaluation.evaluate``'s dict); [] when all pass.
    ``nearest``: each demonstration's nearest other one (index), named in the messages;
    ``extent``: e_i (None: 0); ``follows``: :func:`followed_routes` (the failing demonstrations
    among them get the ``conflicting_demos`` line instead of ``worst_demo``); ``field``: for a
    first-order model, the DTW/point of the data's own first-order field per demonstration
    (:func:`~tamedpuma.puma.data_field.first_order_dtw` at :func:`field_bandwidth`; the
    failing demonstrations it misses too get the ``first_order_data`` line)."""
    field = None if field is None else np.asarray(field, float)
    out = _imitation(evaluation["imitation"], np.asarray(spread, float), names, cfg, unit,
                     nearest, extent, follows, field)
    cv = evaluation["convergence"]
    if cv["converged_fraction"] < cfg.gate_converged:
        out.append(Failure("convergence", (), (
            f"{cv['not_converged']} of {cv['starts']} random starts did not reach the goal "
            f"within {cv['horizon_s']:g} s (farthest ends {_fmt(cv['final_pos_error_max'], unit)}"
            f" away, {cv['final_angle_error_max']:.2f} rad); try another seed (seed=N: a "
            "training can settle on a slow mode at one seed and not at another), or a "
            "workspace the demonstrations cover")))
    cp = evaluation["compatibility"]
    if cp["compatible_fraction"] < cfg.gate_compat:
        out.append(Failure("compatibility", (), (
            f"psi-compatible on {100 * cp['compatible_fraction']:.1f}% of {cp['samples']} "
            f"states (< {100 * cfg.gate_compat:.1f}%): CPM may stall there; try "
            "puma.train.compat_weight=0.3 or puma.train.path_weight=5")))
    return out


def as_report(failures: list[Failure], spread: np.ndarray, cfg: EvalConfig) -> dict:
    """The ``gates`` entry of ``report.json``."""
    return {"passed": not failures, "failures": [asdict(f) for f in failures],
            "spread_median": float(np.median(spread)),
            "spread_per_demo": [float(s) for s in spread],
            "thresholds": {k: getattr(cfg, k) for k in ("gate_spread", "gate_worst", "gate_extent",
                                                        "gate_floor", "gate_converged",
                                                        "gate_compat")}}


def failed_lines(report: dict | None) -> list[str]:
    """The failed gates' lines stored in a report (``[]`` when it passed or has no gates)."""
    gates = (report or {}).get("gates") or {}
    return [str(f.get("line", f)) for f in gates.get("failures", [])]

"""Clutter that keeps a scene feasible: static spheres kept clear of a reference motion.

A *reference motion* is a joint path ``q_0 … q_T`` [rad] that reaches the goal without collision
in the scenario's own world (e.g. a method's run with the scenario's own obstacles,
``tamedpuma/app/reference.py``). Its swept volume is over-approximated by a *skeleton*: at every
configuration of the path, densified so that no skeleton point moves more than ``resolution``
[m] between consecutive samples, the points

    P(q) = {body-sphere centres} ∪ {points every ≤ resolution on each segment between
           consecutive link origins} ∪ {end effector},

each the centre of a ball of radius ``arm_radius`` [m] that covers the link meshes round it
(on the iiwa the URDF's meshes reach 0.133 m from the skeleton on the moving links, 0.15 m on the
base: ``clutter.arm_radius`` = 0.15 m; ``tests/test_clutter.py`` checks the meshes with PyBullet).
The body spheres (radius ≤ 0.09 m) lie inside. A clutter sphere (centre c, radius r) is kept
clear when

    min_p ‖c − p‖ − r − arm_radius ≥ margin + resolution / 2,

the last term covering the motion between samples (a point of the continuous, joint-linear path
lies within resolution / 2 of a sampled one). Every configuration of the reference then has
clearance ≥ margin from every clutter sphere, so the reference stays a collision-free path of the
cluttered scene: the scene is feasible by construction.

Candidates are drawn uniformly in the box [low, high] (``region="box"``) or in a shell of
thickness ``shell`` [m] just outside the kept-clear volume (``region="shell"``: dense round the
reference), and rejected if they violate the condition, overlap the scenario's own obstacles
(at t = 0) or another clutter sphere. Deterministic for a seed (``rng``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tamedpuma.errors import ScenarioError

REGIONS = ("box", "shell")


@dataclass(frozen=True)
class SweptVolume:
    """The skeleton of a reference motion: points (P, 3) [m], each a ball of ``arm_radius`` [m];
    ``resolution`` [m]: the largest motion of a skeleton point between samples."""

    points: np.ndarray
    arm_radius: float
    resolution: float

    def required_distance(self, radius: float, margin: float) -> float:
        """Least centre-to-skeleton distance [m] of a clutter sphere of ``radius`` [m] kept
        ``margin`` [m] clear of the swept volume."""
        return radius + self.arm_radius + margin + 0.5 * self.resolution

    def clearance(self, centers: np.ndarray, radius: float) -> np.ndarray:
        """Surface-to-surface distance [m] of each sphere (centres (n, 3), ``radius``) to the
        sampled swept volume: ``min_p ‖c − p‖ − radius − arm_radius`` per sphere."""
        d, _ = cKDTree(self.points).query(np.asarray(centers, dtype=float).reshape(-1, 3))
        return d - radius - self.arm_radius


def skeleton(kinematics, q: np.ndarray, spacing: float) -> np.ndarray:
    """Skeleton points of the arm at q [m]: body-sphere centres, points at most ``spacing`` [m]
    apart on every segment between consecutive link origins (both ends included), the end
    effector."""
    origins = kinematics.link_poses(q)[0]
    parts = [kinematics.sphere_centers(q)]
    for a, b in zip(origins[:-1], origins[1:]):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / spacing)) + 1)
        parts.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
    parts.append(kinematics.ee_pose(q)[0][None])
    return np.concatenate(parts)


def swept_volume(kinematics, path: np.ndarray, arm_radius: float,
                 resolution: float = 0.02) -> SweptVolume:
    """The :class:`SweptVolume` of a joint path (T, dof) [rad], linearly interpolated between its
    rows so that no skeleton point moves more than ``resolution`` [m] between samples."""
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or len(path) < 1 or not np.all(np.isfinite(path)):
        raise ScenarioError(f"a reference motion must be a finite (T, dof) array, got shape "
                            f"{path.shape}")
    pts = [skeleton(kinematics, path[0], resolution)]
    for q_a, q_b in zip(path[:-1], path[1:]):
        end = skeleton(kinematics, q_b, resolution)
        # the skeleton has the same points at every q (link lengths are fixed): compare rows
        n = int(np.ceil(float(np.linalg.norm(end - pts[-1], axis=1).max()) / resolution))
        # refine until the interpolated samples are close enough (the path is not linear in x)
        while n > 1:
            sub = [skeleton(kinematics, q_a + s * (q_b - q_a), resolution)
                   for s in np.linspace(0.0, 1.0, n + 1)[1:-1]]
            steps = np.diff(np.stack([pts[-1], *sub, end]), axis=0)
            worst = float(np.linalg.norm(steps, axis=-1).max())
            if worst <= resolution:
                pts.extend(sub)
                break
            n = int(np.ceil(n * worst / resolution)) + 1
        pts.append(end)
    points = np.unique(np.round(np.concatenate(pts), 6), axis=0)
    return SweptVolume(points, float(arm_radius), float(resolution))


def place_clutter(count: int, radius: float, low, high, volume: SweptVolume, margin: float,
                  own_centers: np.ndarray, own_radii: np.ndarray, rng: np.random.Generator,
                  *, region: str = "box", shell: float = 0.3,
                  max_tries: int = 500_000) -> np.ndarray:
    """Centres (count, 3) [m] of ``count`` static clutter spheres of ``radius`` [m] in the box
    [low, high] [m], kept ``margin`` [m] clear of ``volume`` (see the module docstring), not
    overlapping the scenario's own obstacles (``own_centers`` (m, 3), ``own_radii`` (m,)) nor
    each other. ``region``: 'box' (uniform in the box) or 'shell' (uniform distance in
    [D, D + shell] [m] from a random skeleton point, D the least allowed distance: dense round
    the reference). Raises :class:`ScenarioError` (one line) if ``count`` do not fit within
    ``max_tries`` candidates."""
    if region not in REGIONS:
        raise ScenarioError(f"clutter.region must be one of {', '.join(REGIONS)}, got {region!r}")
    if count <= 0:
        return np.zeros((0, 3))
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    own_centers = np.asarray(own_centers, dtype=float).reshape(-1, 3)
    own_radii = np.asarray(own_radii, dtype=float).reshape(-1)
    need = volume.required_distance(radius, margin)
    tree = cKDTree(volume.points)
    chosen = np.zeros((count, 3))
    n, tries = 0, 0
    while n < count:
        if tries >= max_tries:
            raise ScenarioError(
                f"cannot place {count} clutter spheres of radius {radius} m kept {margin} m "
                f"clear of the reference motion in the box {low.tolist()}..{high.tolist()} "
                f"(region={region}): only {n} fit after {tries} candidates")
        size = max(256, 2 * (count - n))
        tries += size
        if region == "box":
            batch = rng.uniform(low, high, size=(size, 3))
        else:
            base = volume.points[rng.integers(0, len(volume.points), size)]
            direction = rng.normal(size=(size, 3))
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            batch = base + direction * rng.uniform(need, need + shell, size)[:, None]
        ok = np.all((batch >= low) & (batch <= high), axis=1)
        ok &= tree.query(batch)[0] >= need
        if len(own_centers):
            gap = (np.linalg.norm(batch[:, None] - own_centers[None], axis=-1)
                   - radius - own_radii[None])
            ok &= gap.min(axis=1) > 0
        for center in batch[ok]:  # no two clutter spheres overlap
            if n == count:
                break
            if n == 0 or np.linalg.norm(chosen[:n] - center, axis=1).min() > 2 * radius:
                chosen[n] = center
                n += 1
    return chosen

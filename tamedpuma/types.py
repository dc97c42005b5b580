"""The nouns every module shares: scenarios, observations, commands and the controller protocol.

numpy only. Units: metres, radians, seconds. Quaternions are (x, y, z, w) everywhere.
All arrays held by these frozen dataclasses are made read-only on construction.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

#: Clearance [m] logged when the scene has no obstacle: a large finite number, so every log
#: (MCAP, Rerun, ``summary.json``) holds plain finite floats.
NO_OBSTACLE_CLEARANCE = 1.0e3


def frozen_array(value, shape: tuple[int | None, ...], name: str) -> np.ndarray:
    """Return ``value`` as a read-only float64 array of ``shape`` (None = any length)."""
    arr = np.array(value, dtype=float)
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr}")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class Obstacles:
    """Sphere obstacles moving with constant velocity: ``o_j(t) = o_j(0) + t v_j`` [m].

    centers: (n, 3) centres at t = 0 [m]; radii: (n,) [m]; velocities: (n, 3) [m/s].
    The count n is run-time data (0 allowed).
    """

    centers: np.ndarray
    radii: np.ndarray
    velocities: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "centers", frozen_array(
            np.reshape(self.centers, (-1, 3)), (None, 3), "obstacle centers"))
        n = len(self.centers)
        object.__setattr__(self, "radii", frozen_array(
            np.reshape(self.radii, (-1,)), (n,), "obstacle radii"))
        object.__setattr__(self, "velocities", frozen_array(
            np.reshape(self.velocities, (-1, 3)), (n, 3), "obstacle velocities"))
        if np.any(self.radii <= 0):
            raise ValueError("obstacle radii must be positive")

    @staticmethod
    def empty() -> Obstacles:
        return Obstacles(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))

    def __len__(self) -> int:
        return len(self.radii)

    def at(self, t: float) -> np.ndarray:
        """Centres at time t [s]: (n, 3) [m]."""
        return self.centers + t * self.velocities


@dataclass(frozen=True)
class Goal:
    """End-effector goal pose, possibly moving: ``p_g(t) = p_g(0) + t v_g``.

    position: (3,) [m]; quaternion: (4,) (x, y, z, w), unit; velocity: (3,) [m/s].
    """

    position: np.ndarray
    quaternion: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        object.__setattr__(self, "position", frozen_array(self.position, (3,), "goal position"))
        quat = np.array(self.quaternion, dtype=float)
        norm = np.linalg.norm(quat) if quat.shape == (4,) else 0.0
        if not norm > 0:
            raise ValueError(f"goal quaternion must be a non-zero (x, y, z, w), got {quat}")
        object.__setattr__(self, "quaternion", frozen_array(quat / norm, (4,), "goal quaternion"))
        object.__setattr__(self, "velocity", frozen_array(self.velocity, (3,), "goal velocity"))

    def at(self, t: float) -> np.ndarray:
        """Goal position at time t [s]: (3,) [m]."""
        return self.position + t * self.velocity


@dataclass(frozen=True)
class Scenario:
    """Everything that defines one episode, independent of the method that drives it.

    q0: (dof,) start configuration [rad] (already inside the joint limits; dof: the robot's
    joint count, its config's);
    dt: control period [s]; max_steps: episode length limit; goal_tolerance: success radius [m].
    """

    name: str
    task: str
    q0: np.ndarray
    goal: Goal
    obstacles: Obstacles
    dt: float
    max_steps: int
    goal_tolerance: float
    seed: int = 0

    def __post_init__(self):
        object.__setattr__(self, "q0", frozen_array(np.ravel(self.q0), (None,), "q0"))
        if not self.dt > 0:
            raise ValueError(f"dt must be positive, got {self.dt}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        if not self.goal_tolerance > 0:
            raise ValueError(f"goal_tolerance must be positive, got {self.goal_tolerance}")


@dataclass(frozen=True)
class Observation:
    """What the controller sees at the start of a control step (simulator truth).

    t: time [s]; step: control step index; q, qd: (dof,) joint position [rad] and velocity [rad/s];
    obstacle_centers, obstacle_velocities: (n, 3) [m], [m/s]; obstacle_radii: (n,) [m];
    goal_position: (3,) [m]; goal_quaternion: (4,) (x, y, z, w); goal_velocity (3,) [m/s].
    """

    t: float
    step: int
    q: np.ndarray
    qd: np.ndarray
    obstacle_centers: np.ndarray
    obstacle_radii: np.ndarray
    obstacle_velocities: np.ndarray
    goal_position: np.ndarray
    goal_quaternion: np.ndarray
    goal_velocity: np.ndarray


@dataclass(frozen=True)
class Command:
    """A controller's output for one step.

    qdd: (dof,) desired joint acceleration [rad/s²]; the simulator commands the joint velocity
    ``clip(q̇ + q̈ Δt, ±q̇_max)``. scalars: the method's internals for the log
    (energies, α, β, ψ, ...). logged_later: scalars for the log that the step itself does not
    need (e.g. PUMA's ψ where the step never evaluates it): called after the step is timed
    (off the control path: not in ``compute_time_ms``), and only when a recorder takes the
    step; before the next step, while the state the step saw is still current.
    """

    qdd: np.ndarray
    scalars: Mapping[str, float] = field(default_factory=dict)
    logged_later: Callable[[], Mapping[str, float]] | None = None


@dataclass(frozen=True)
class Contacts:
    """Contact and clearance at one instant.

    sphere_clearance: min over (body sphere i, obstacle j) of ‖c_i − o_j‖ − r_i − r_j [m]
    (inf without obstacles); obstacle_contact: PyBullet reports a robot–obstacle contact;
    ground_contact: a robot link other than the base touches the ground plane.
    """

    sphere_clearance: float
    obstacle_contact: bool
    ground_contact: bool


class World(Protocol):
    """What the episode loop (:func:`tamedpuma.episode.run_episode`) drives: PyBullet's arm
    (:class:`tamedpuma.worlds.bullet.Simulator`) and the 2-D point robot
    (:class:`tamedpuma.worlds.pointmass.PointMassWorld`) implement it. Positions [m], times [s]."""

    spec: Any  # the robot's RobotSpec (dof, links, limits, body spheres)

    def reset(self, scenario: Scenario) -> Observation: ...

    def step(self, qdd: np.ndarray) -> Observation: ...

    def link_poses(self) -> tuple[np.ndarray, np.ndarray]: ...

    def body_sphere_centers(self, link_pos: np.ndarray,
                            link_quat: np.ndarray) -> np.ndarray: ...

    def contacts(self, sphere_centers: np.ndarray) -> Contacts: ...

    def obstacle_centers(self, t: float | None = None) -> np.ndarray:
        """The obstacles' true centres at ``t`` (now if None), shape (n, 3): what the logs
        record, whatever noise the controller's observation carries."""
        ...

    @property
    def disturbance_time(self) -> float | None:
        """The onset [s] of the scenario's discrete disturbance (goal change, push), else None."""
        ...

    def close(self) -> None: ...


class Controller(Protocol):
    """A method: ``reset`` once per episode, then ``step`` once per control period. The
    built-in methods keep everything ``step`` writes in an ``episode`` attribute that ``reset``
    makes afresh (docs/extending.md, "Episode state")."""

    def reset(self, scenario: Scenario) -> None: ...

    def step(self, obs: Observation) -> Command: ...

"""A 2-D point-mass world for fast tests and figures: the same loop, methods and recorders as the
arm, without PyBullet (the kinematics types come from :mod:`tamedpuma.robot.kinematics`).

The robot is a disc of radius 0.2 at q = (x, y) [m] in the plane z = 0; its "kinematics" is the
identity (end effector = body sphere = (x, y, 0), J = [I₂; 0]). The world integrates the same
control law as the arm's simulator, exactly: ``q̇ ← clip(q̇ + q̈ Δt, ±q̇_max)``, ``q ← q + q̇ Δt``
(semi-implicit Euler). Obstacles are discs (spheres at z = 0) moving with constant velocity.

The reference scene (issue: the authors' point-robot example): start (0, 0), goal
(−2.4355761, −7.5252747), obstacles at (0, −6.6) radius 0.7 and (−2, −4) radius 1.0.
"""

from __future__ import annotations

import math

import numpy as np

from tamedpuma.robot.kinematics import KinematicState, RobotSpec
from tamedpuma.types import Contacts, Goal, Observation, Obstacles, Scenario

POINT_START = (0.0, 0.0)
POINT_GOAL = (-2.4355761, -7.5252747)
POINT_OBSTACLES = (((0.0, -6.6), 0.7), ((-2.0, -4.0), 1.0))
POINT_RADIUS = 0.2


def point_spec(radius: float = POINT_RADIUS, speed_limit: float = 2.0,
               bound: float = 100.0) -> RobotSpec:
    """The point robot as a :class:`RobotSpec`: 2 "joints" x, y [m] within ±bound, speed limit
    [m/s] per axis, one body sphere of ``radius`` [m]."""
    from tamedpuma.robot.kinematics import BodySphere

    return RobotSpec(urdf_path="", joint_names=("x", "y"), link_names=("point",),
                     ee_link="point", q_min=np.full(2, -bound), q_max=np.full(2, bound),
                     qd_max=np.full(2, speed_limit),
                     spheres=(BodySphere(link="point", radius=radius),))


def point_scenario(obstacles: bool = True, max_steps: int = 1500, dt: float = 0.02) -> Scenario:
    """The reference scene (with or without its two obstacles)."""
    obst = Obstacles.empty()
    if obstacles:
        obst = Obstacles([[x, y, 0.0] for (x, y), _ in POINT_OBSTACLES],
                         [r for _, r in POINT_OBSTACLES], np.zeros((len(POINT_OBSTACLES), 3)))
    return Scenario(name="point" if obstacles else "point_free", task="point",
                    q0=np.array(POINT_START), goal=Goal([*POINT_GOAL, 0.0], [0, 0, 0, 1]),
                    obstacles=obst, dt=dt, max_steps=max_steps, goal_tolerance=0.05)


class PointKinematics:
    """Identity kinematics of the point robot, with the interface of
    :class:`tamedpuma.robot.kinematics.Kinematics` (``spec``, ``evaluate``, ``ee_pose``, ...)."""

    def __init__(self, spec: RobotSpec):
        self.spec = spec
        jac = np.zeros((6, 2))
        jac[0, 0] = jac[1, 1] = 1.0
        self._jac = jac
        self._sphere_jac = jac[None, :3, :].copy()
        self._radii = spec.sphere_radii

    def evaluate(self, q: np.ndarray, qd: np.ndarray) -> KinematicState:
        p = np.array([q[0], q[1], 0.0])
        return KinematicState(
            ee_position=p, ee_rotation=np.eye(3), ee_quaternion=np.array([0.0, 0, 0, 1]),
            ee_jacobian=self._jac, ee_jdqd=np.zeros(6), sphere_centers=p[None],
            sphere_jacobians=self._sphere_jac, sphere_jdqd=np.zeros((1, 3)),
            sphere_radii=self._radii)

    def ee_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.array([q[0], q[1], 0.0]), np.array([0.0, 0, 0, 1])

    def sphere_centers(self, q: np.ndarray) -> np.ndarray:
        return np.array([[q[0], q[1], 0.0]])

    def link_poses(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.sphere_centers(q), np.array([[0.0, 0, 0, 1]])


class PointMassWorld:
    """The 2-D world: a :class:`tamedpuma.types.World`, as PyBullet's arm is."""

    def __init__(self, spec: RobotSpec | None = None):
        self.spec = spec or point_spec()
        self._scenario: Scenario | None = None

    def reset(self, scenario: Scenario) -> Observation:
        if len(scenario.q0) != 2:
            raise ValueError(f"the point robot needs a 2-D start, got {scenario.q0}")
        self._scenario = scenario
        self._q = np.array(scenario.q0, dtype=float)
        self._qd = np.zeros(2)
        self._step = 0
        return self.observe()

    @property
    def t(self) -> float:
        return self._step * self._scenario.dt

    def step(self, qdd: np.ndarray) -> Observation:
        dt = self._scenario.dt
        self._qd = np.clip(self._qd + np.asarray(qdd, dtype=float) * dt, -self.spec.qd_max,
                           self.spec.qd_max)
        self._q = self._q + self._qd * dt
        self._step += 1
        return self.observe()

    def observe(self) -> Observation:
        sc, t = self._scenario, self.t
        return Observation(t=t, step=self._step, q=self._q.copy(), qd=self._qd.copy(),
                           obstacle_centers=sc.obstacles.at(t), obstacle_radii=sc.obstacles.radii,
                           obstacle_velocities=sc.obstacles.velocities,
                           goal_position=sc.goal.at(t), goal_quaternion=sc.goal.quaternion,
                           goal_velocity=sc.goal.velocity)

    def obstacle_centers(self, t: float | None = None) -> np.ndarray:
        """The obstacles' centres at ``t`` (now if None): the observation's, without noise."""
        return self._scenario.obstacles.at(self.t if t is None else t)

    @property
    def disturbance_time(self) -> float | None:
        """None: the point world has no discrete disturbance."""
        return None

    def link_poses(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array([[self._q[0], self._q[1], 0.0]]), np.array([[0.0, 0, 0, 1]])

    def body_sphere_centers(self, link_pos: np.ndarray, link_quat: np.ndarray) -> np.ndarray:
        return link_pos[:1].copy()

    def contacts(self, sphere_centers: np.ndarray) -> Contacts:
        sc = self._scenario
        if not len(sc.obstacles):
            return Contacts(math.inf, False, False)
        gaps = (np.linalg.norm(sphere_centers[:1] - sc.obstacles.at(self.t), axis=1)
                - self.spec.sphere_radii[0] - sc.obstacles.radii)
        clearance = float(gaps.min())
        return Contacts(clearance, clearance < 0, False)

    def close(self) -> None:
        pass

    def __enter__(self) -> PointMassWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

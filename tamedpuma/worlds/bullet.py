"""The PyBullet world: robot on a fixed base, ground, sphere obstacles, goal marker.

The only module that imports PyBullet. It knows the robot (a :class:`RobotSpec`) and the scenario,
never the method that drives it.

Control: every control period Δt [s] the controller's joint acceleration q̈ [rad/s²] becomes a
joint-velocity target ``q̇_cmd = clip(q̇ + q̈ Δt, ±q̇_max)`` [rad/s], held for Δt / substep PyBullet
steps of 1 ms. Obstacles move kinematically, ``o(t) = o₀ + t v``, updated once per control period.
Each simulator owns its own PyBullet client (DIRECT by default), so runs are independent and the
same inputs give the identical trajectory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from tamedpuma.robot.kinematics import RobotSpec
from tamedpuma.types import Contacts, Observation, Scenario


@dataclass(frozen=True)
class SimConfig:
    """gui: open a window; substep: physics step [s]; gravity [m/s²] along −z;
    max_joint_force: motor force limit [N·m] of the velocity controller; ground: add a plane."""

    gui: bool = False
    substep: float = 0.001
    gravity: float = 9.81
    max_joint_force: float = 500.0
    ground: bool = True


class Simulator:
    """A PyBullet world for one robot. ``reset(scenario)`` then ``step(q̈)`` per control period."""

    def __init__(self, spec: RobotSpec, config: SimConfig = SimConfig()):
        self.spec = spec
        self.config = config
        self._client = pb.connect(pb.GUI if config.gui else pb.DIRECT)
        self._robot = -1
        self._obstacle_ids: list[int] = []
        self._scenario: Scenario | None = None
        self._step = 0
        self._qd_cmd = np.zeros(spec.dof)

    # -- set-up -----------------------------------------------------------------------------
    def reset(self, scenario: Scenario) -> Observation:
        """Build the world for ``scenario`` (robot at q0, at rest); return the first observation."""
        if len(scenario.q0) != self.spec.dof:
            raise ValueError(f"q0 has {len(scenario.q0)} joints, robot has {self.spec.dof}")
        c = self._client
        pb.resetSimulation(physicsClientId=c)
        pb.setGravity(0, 0, -self.config.gravity, physicsClientId=c)
        n_sub = round(scenario.dt / self.config.substep)
        if n_sub < 1 or not math.isclose(n_sub * self.config.substep, scenario.dt, rel_tol=1e-9):
            raise ValueError(f"dt {scenario.dt} is not a multiple of the substep "
                             f"{self.config.substep}")
        self._n_sub = n_sub
        pb.setPhysicsEngineParameter(fixedTimeStep=self.config.substep, numSubSteps=0,
                                     deterministicOverlappingPairs=1, physicsClientId=c)
        if self.config.ground:
            import pybullet_data

            pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=c)
            self._ground = pb.loadURDF("plane.urdf", physicsClientId=c)
        else:
            self._ground = -1
        self._robot = pb.loadURDF(self.spec.urdf_path, basePosition=[0, 0, 0], useFixedBase=True,
                                  physicsClientId=c)
        names = [pb.getJointInfo(self._robot, i, physicsClientId=c)[1].decode()
                 for i in range(pb.getNumJoints(self._robot, physicsClientId=c))]
        self._joint_idx = [names.index(n) for n in self.spec.joint_names]
        link_of_joint = {pb.getJointInfo(self._robot, i, physicsClientId=c)[12].decode(): i
                         for i in range(len(names))}
        # link index -1 is the base (the first logged link, at the world origin)
        self._link_idx = [link_of_joint.get(n, -1) for n in self.spec.link_names]
        self._sphere_link = [self.spec.link_names.index(s.link) for s in self.spec.spheres]
        self._sphere_offset = np.array([s.offset for s in self.spec.spheres]).reshape(-1, 3)
        self._sphere_radii = self.spec.sphere_radii
        for j, q in zip(self._joint_idx, scenario.q0):
            pb.resetJointState(self._robot, j, float(q), 0.0, physicsClientId=c)
        # velocity motors hold the arm; gravity is compensated by the motor force
        pb.setJointMotorControlArray(self._robot, self._joint_idx, pb.VELOCITY_CONTROL,
                                     targetVelocities=[0.0] * self.spec.dof,
                                     forces=[self.config.max_joint_force] * self.spec.dof,
                                     physicsClientId=c)
        self._obstacle_ids = self._add_obstacles(scenario)
        self._goal_marker = self._add_goal_marker(scenario)
        self._scenario = scenario
        self._step = 0
        return self.observe()

    def _add_obstacles(self, scenario: Scenario) -> list[int]:
        c = self._client
        ids = []
        for center, radius in zip(scenario.obstacles.centers, scenario.obstacles.radii):
            col = pb.createCollisionShape(pb.GEOM_SPHERE, radius=float(radius), physicsClientId=c)
            vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=float(radius),
                                       rgbaColor=[0.8, 0.2, 0.2, 1.0], physicsClientId=c)
            ids.append(pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=col,
                                          baseVisualShapeIndex=vis,
                                          basePosition=center.tolist(), physicsClientId=c))
        return ids

    def _add_goal_marker(self, scenario: Scenario) -> int:
        c = self._client
        vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=0.02, rgbaColor=[0.1, 0.8, 0.1, 0.6],
                                   physicsClientId=c)
        return pb.createMultiBody(baseMass=0, baseVisualShapeIndex=vis,
                                  basePosition=scenario.goal.position.tolist(), physicsClientId=c)

    # -- stepping ---------------------------------------------------------------------------
    @property
    def t(self) -> float:
        """Simulated time [s]."""
        return self._step * self._scenario.dt

    def step(self, qdd: np.ndarray) -> Observation:
        """Apply q̈ [rad/s²] for one control period and return the next observation."""
        sc = self._scenario
        c = self._client
        qd = self._joint_velocities()
        qd_cmd = np.clip(qd + np.asarray(qdd, dtype=float) * sc.dt,
                         -self.spec.qd_max, self.spec.qd_max)
        self._qd_cmd = qd_cmd
        pb.setJointMotorControlArray(self._robot, self._joint_idx, pb.VELOCITY_CONTROL,
                                     targetVelocities=qd_cmd.tolist(),
                                     forces=[self.config.max_joint_force] * self.spec.dof,
                                     physicsClientId=c)
        for _ in range(self._n_sub):
            pb.stepSimulation(physicsClientId=c)
        self._step += 1
        t = self.t
        if np.any(sc.obstacles.velocities != 0):
            for oid, center in zip(self._obstacle_ids, sc.obstacles.at(t)):
                pb.resetBasePositionAndOrientation(oid, center.tolist(), [0, 0, 0, 1],
                                                   physicsClientId=c)
        if np.any(sc.goal.velocity != 0):
            pb.resetBasePositionAndOrientation(self._goal_marker, sc.goal.at(t).tolist(),
                                               [0, 0, 0, 1], physicsClientId=c)
        return self.observe()

    def _joint_velocities(self) -> np.ndarray:
        states = pb.getJointStates(self._robot, self._joint_idx, physicsClientId=self._client)
        return np.array([s[1] for s in states])

    def observe(self) -> Observation:
        """The current state as an :class:`Observation` (simulator truth)."""
        sc = self._scenario
        states = pb.getJointStates(self._robot, self._joint_idx, physicsClientId=self._client)
        t = self.t
        return Observation(
            t=t,
            step=self._step,
            q=np.array([s[0] for s in states]),
            qd=np.array([s[1] for s in states]),
            obstacle_centers=sc.obstacles.at(t),
            obstacle_radii=sc.obstacles.radii,
            obstacle_velocities=sc.obstacles.velocities,
            goal_position=sc.goal.at(t),
            goal_quaternion=sc.goal.quaternion,
            goal_velocity=sc.goal.velocity,
        )

    @property
    def last_velocity_command(self) -> np.ndarray:
        """The joint-velocity target of the last step [rad/s]."""
        return self._qd_cmd

    # -- queries ----------------------------------------------------------------------------
    def link_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """World poses of ``spec.link_names``: positions (L, 3) [m], quaternions (L, 4) xyzw."""
        c = self._client
        movable = [i for i in self._link_idx if i >= 0]
        states = pb.getLinkStates(self._robot, movable, computeForwardKinematics=True,
                                  physicsClientId=c)
        by_index = {i: s for i, s in zip(movable, states)}
        pos = np.zeros((len(self._link_idx), 3))
        quat = np.tile([0.0, 0.0, 0.0, 1.0], (len(self._link_idx), 1))
        for k, i in enumerate(self._link_idx):
            if i >= 0:
                pos[k] = by_index[i][4]
                quat[k] = by_index[i][5]
        return pos, quat

    def body_sphere_centers(self, link_pos: np.ndarray, link_quat: np.ndarray) -> np.ndarray:
        """Collision-sphere centres (k, 3) [m] from link poses (as returned by link_poses)."""
        centers = link_pos[self._sphere_link].copy()
        for i, (k, off) in enumerate(zip(self._sphere_link, self._sphere_offset)):
            if np.any(off):
                rot = np.array(pb.getMatrixFromQuaternion(link_quat[k].tolist())).reshape(3, 3)
                centers[i] += rot @ off
        return centers

    def contacts(self, sphere_centers: np.ndarray) -> Contacts:
        """Clearance of the body spheres and PyBullet contacts of the robot at this instant."""
        sc = self._scenario
        c = self._client
        if len(sc.obstacles):
            obst = sc.obstacles.at(self.t)
            gaps = (np.linalg.norm(sphere_centers[:, None, :] - obst[None, :, :], axis=-1)
                    - self._sphere_radii[:, None] - sc.obstacles.radii[None, :])
            clearance = float(gaps.min())
        else:
            clearance = math.inf
        obstacle_set = set(self._obstacle_ids)
        obstacle_contact = False
        ground_contact = False
        for cp in pb.getContactPoints(bodyA=self._robot, physicsClientId=c):
            other, link = cp[2], cp[3]
            if other in obstacle_set:
                obstacle_contact = True
            elif other == self._ground and link >= 0:
                ground_contact = True
        return Contacts(clearance, obstacle_contact, ground_contact)

    def close(self) -> None:
        if self._client is not None and pb.isConnected(self._client):
            pb.disconnect(self._client)
        self._client = None

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""The PyBullet world: robot on a fixed base, ground, sphere obstacles, goal marker.

The only module that imports PyBullet. It knows the robot (a :class:`RobotSpec`) and the scenario,
never the method that drives it.

Control (``SimConfig.control``): every control period Δt [s] the controller's joint acceleration
q̈ [rad/s²] becomes the velocity target ``q̇_cmd = clip(q̇_k + q̈ Δt, ±q̇_max)`` [rad/s], i.e. the
acceleration ``a = (q̇_cmd − q̇_k)/Δt``, and is then tracked over the Δt / substep PyBullet steps of
1 ms by

- ``velocity`` (default): PyBullet's velocity motors hold q̇_cmd (force limit ``max_joint_force``);
- ``impedance``: a 1 kHz joint impedance (torque) controller with gravity compensation, as on the
  real iiwa, with the robot's gains K, D and torque limits (``robot.impedance``,
  :class:`~tamedpuma.robot.kinematics.JointImpedance`): at each substep, τ after the period start,
  ``q_d = q_k + q̇_k τ + ½ a τ²``, ``q̇_d = q̇_k + a τ`` and the torque [N·m]
  ``u = g(q) + K (q_d − q) + D (q̇_d − q̇)`` (+ ``M(q) a + c(q, q̇)`` when ``feedforward``: the
  inverse dynamics of a at the measured state, which contains g), clipped to ``torque_limit``.
  With a 30 Hz policy use Δt = 0.033 s (``disturbance=impedance`` sets it).

Obstacles move kinematically, ``o(t) = o₀ + t v``, updated once per control period.

Disturbances (:class:`Disturbance`, ``conf/disturbance/``): ``goal_change`` (from ``onset`` the
goal is displaced by ``goal_offset`` [m], seen at once by the controller); ``push`` (an external
force ``force`` [N], world frame, at the origin of ``link`` for ``duration`` s from ``onset``,
applied at every physics substep); ``obstacle_noise`` (the controller sees obstacle centres
sampled at ``sensor_rate`` [Hz] with i.i.d. Gaussian noise of std ``noise_std`` [m] per axis, held
between samples, seeded by the scenario seed; the true positions decide every clearance and
contact, and are what the recorders log).

Each simulator owns its own PyBullet client (DIRECT by default), so runs are independent and the
same inputs give the identical trajectory.
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from tamedpuma.errors import ScenarioError
from tamedpuma.robot.kinematics import RobotSpec
from tamedpuma.robot.rotations import bullet_rotation_matrices
from tamedpuma.types import Contacts, Observation, Scenario
from tamedpuma.worlds.settings import (  # noqa: F401 - re-exported: the simulator's settings
    CONTROL_MODES,
    DISTURBANCE_KINDS,
    Disturbance,
    SimConfig,
)


class Simulator:
    """A PyBullet world for one robot. ``reset(scenario)`` then ``step(q̈)`` per control period."""

    def __init__(self, spec: RobotSpec, config: SimConfig = SimConfig(),  # noqa: B008 (frozen)
                 disturbance: Disturbance = Disturbance()):  # noqa: B008
        if config.control == "impedance" and spec.impedance is None:
            raise ValueError("impedance control needs the robot's joint impedance gains "
                             "(robot.impedance)")
        self.spec = spec
        self.config = config
        self.disturbance = disturbance
        self._client = pb.connect(pb.GUI if config.gui else pb.DIRECT)
        self._robot = -1
        self._obstacle_ids: list[int] = []
        self._scenario: Scenario | None = None
        self._step = 0
        self._qd_cmd = np.zeros(spec.dof)
        self._joint_cache = None

    # -- set-up -----------------------------------------------------------------------------
    def reset(self, scenario: Scenario) -> Observation:
        """Build the world for ``scenario`` (robot at q0, at rest); return the first observation."""
        if len(scenario.q0) != self.spec.dof:
            raise ValueError(f"q0 has {len(scenario.q0)} joints, robot has {self.spec.dof}")
        self._reset_physics(scenario.dt)
        self._load_robot(scenario.q0)
        self._hold_robot()
        self._set_up_disturbance(scenario.seed)
        self._obstacle_ids = self._add_obstacles(scenario)
        self._obstacle_set = frozenset(self._obstacle_ids)
        self._scenario = scenario
        self._goal_marker = self._add_goal_marker(scenario)
        self._step = 0
        self._set_run_constants(scenario)
        self._joint_cache = None  # (q, qd) read since the last physics step
        return self.observe()

    def _reset_physics(self, dt: float) -> None:
        """An empty world: gravity, ``dt / substep`` physics substeps per step, the ground."""
        c = self._client
        pb.resetSimulation(physicsClientId=c)
        self._joint_cache = None
        pb.setGravity(0, 0, -self.config.gravity, physicsClientId=c)
        n_sub = round(dt / self.config.substep)
        if n_sub < 1 or not math.isclose(n_sub * self.config.substep, dt, rel_tol=1e-9):
            raise ScenarioError(f"scenario.dt {dt} s is not a multiple (>= 1) of the "
                                f"simulator's substep {self.config.substep} s")
        self._n_sub = n_sub
        pb.setPhysicsEngineParameter(fixedTimeStep=self.config.substep, numSubSteps=0,
                                     deterministicOverlappingPairs=1, physicsClientId=c)
        if self.config.ground:
            import pybullet_data

            pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=c)
            self._ground = pb.loadURDF("plane.urdf", physicsClientId=c)
        else:
            self._ground = -1

    def _load_robot(self, q0: np.ndarray) -> None:
        """The robot's URDF on a fixed base at q0, at rest; PyBullet's indices of its joints, logged
        links and body-sphere links."""
        c = self._client
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
        for j, q in zip(self._joint_idx, q0):
            pb.resetJointState(self._robot, j, float(q), 0.0, physicsClientId=c)

    def _hold_robot(self) -> None:
        """The joint motors: velocity motors hold the arm (gravity is compensated by the motor
        force); in impedance mode they are switched off (force 0) and the torques act alone."""
        c = self._client
        motor_force = self.config.max_joint_force if self.config.control == "velocity" else 0.0
        pb.setJointMotorControlArray(self._robot, self._joint_idx, pb.VELOCITY_CONTROL,
                                     targetVelocities=[0.0] * self.spec.dof,
                                     forces=[motor_force] * self.spec.dof,
                                     physicsClientId=c)
        n_joints = pb.getNumJoints(self._robot, physicsClientId=c)
        movable = [i for i in range(n_joints)
                   if pb.getJointInfo(self._robot, i, physicsClientId=c)[2] != pb.JOINT_FIXED]
        if self.config.control == "impedance" and movable != list(self._joint_idx):
            raise ValueError("impedance control needs the actuated joints to be all the "
                             "robot's movable joints")

    def _set_up_disturbance(self, seed: int) -> None:
        """The pushed link (``push``) and the sensor-noise generator (``obstacle_noise``)."""
        dist = self.disturbance
        self._push_link = -1
        if dist.kind == "push":
            link = self.spec.ee_link if dist.link is None else dist.link
            if link not in self.spec.link_names:
                raise ValueError(f"disturbance.link {link!r} is not one of "
                                 f"{list(self.spec.link_names)}")
            self._push_link = self._link_idx[self.spec.link_names.index(link)]
        self._noise_rng = np.random.default_rng([int(seed), 4243])
        self._sensor_sample = -1
        self._sensed_centers = None

    def _set_run_constants(self, scenario: Scenario) -> None:
        """Per-run constants of the hot path (``step``, ``link_poses``, ``body_sphere_centers``)."""
        dist = self.disturbance
        self._moving_obstacles = bool(np.any(scenario.obstacles.velocities != 0))
        self._moving_goal = (bool(np.any(scenario.goal.velocity != 0))
                             or dist.kind == "goal_change")
        self._plain_substeps = self.config.control == "velocity" and dist.kind != "push"
        self._motor_forces = [self.config.max_joint_force] * self.spec.dof
        self._movable_links = [i for i in self._link_idx if i >= 0]
        quat = np.zeros((len(self._link_idx), 4))
        quat[:, 3] = 1.0  # the base (index -1) at the world origin
        self._base_pose = (np.zeros((len(self._link_idx), 3)), quat)
        rows = [k for k, i in enumerate(self._link_idx) if i >= 0]
        # the rows PyBullet's link states fill: a slice when consecutive (every link but the
        # base), which numpy fills from the list of tuples about 3x faster than an index array
        self._movable_rows = (slice(rows[0], rows[-1] + 1)
                              if rows and rows == list(range(rows[0], rows[-1] + 1))
                              else np.array(rows, dtype=int))
        self._any_movable = bool(rows)
        self._offset_spheres = np.flatnonzero(np.any(self._sphere_offset != 0, axis=1))
        self._offset_links = np.asarray(self._sphere_link, dtype=int)[self._offset_spheres]

    def _add_obstacles(self, scenario: Scenario) -> list[int]:
        c = self._client
        ids, shapes = [], {}
        for center, radius in zip(scenario.obstacles.centers, scenario.obstacles.radii):
            radius = float(radius)
            if radius not in shapes:  # one shape per radius, shared (clutter: one for all)
                shapes[radius] = (
                    pb.createCollisionShape(pb.GEOM_SPHERE, radius=radius, physicsClientId=c),
                    pb.createVisualShape(pb.GEOM_SPHERE, radius=radius,
                                         rgbaColor=[0.8, 0.2, 0.2, 1.0], physicsClientId=c))
            col, vis = shapes[radius]
            # maximal coordinates: a plain rigid body, not a multibody that every physics step
            # updates (1000 obstacles: about half the step time; the same contacts)
            ids.append(pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=col,
                                          baseVisualShapeIndex=vis,
                                          basePosition=center.tolist(),
                                          useMaximalCoordinates=True, physicsClientId=c))
        return ids

    def _add_goal_marker(self, scenario: Scenario) -> int:
        c = self._client
        vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=0.02, rgbaColor=[0.1, 0.8, 0.1, 0.6],
                                   physicsClientId=c)
        return pb.createMultiBody(baseMass=0, baseVisualShapeIndex=vis,
                                  basePosition=self.goal_position(0.0).tolist(),
                                  physicsClientId=c)

    # -- stepping ---------------------------------------------------------------------------
    @property
    def t(self) -> float:
        """Simulated time [s]."""
        return self._step * self._scenario.dt

    @property
    def disturbance_time(self) -> float | None:
        """Onset [s] of the configured discrete disturbance (goal change, push), else None."""
        return self.disturbance.onset_time

    def goal_position(self, t: float) -> np.ndarray:
        """The goal at time t [s]: the scenario's, displaced from the onset of a goal change."""
        goal = self._scenario.goal.at(t)
        dist = self.disturbance
        if dist.kind == "goal_change" and t >= dist.onset - 1e-9:
            goal = goal + np.asarray(dist.goal_offset, dtype=float)
        return goal

    def step(self, qdd: np.ndarray) -> Observation:
        """Apply q̈ [rad/s²] for one control period and return the next observation."""
        sc = self._scenario
        c = self._client
        q0, qd = self._joint_state()
        qd_cmd = np.clip(qd + np.asarray(qdd, dtype=float) * sc.dt,
                         -self.spec.qd_max, self.spec.qd_max)
        self._qd_cmd = qd_cmd
        if self.config.control == "velocity":
            pb.setJointMotorControlArray(self._robot, self._joint_idx, pb.VELOCITY_CONTROL,
                                         targetVelocities=qd_cmd.tolist(),
                                         forces=self._motor_forces, physicsClientId=c)
        self._joint_cache = None
        if self._plain_substeps:  # velocity motors, no push: nothing to do between substeps
            for _ in range(self._n_sub):
                pb.stepSimulation(physicsClientId=c)
        else:
            acc = (qd_cmd - qd) / sc.dt
            t0 = self.t
            for i in range(self._n_sub):
                tau = i * self.config.substep
                if self.config.control == "impedance":
                    self._apply_impedance(q0 + qd * tau + 0.5 * acc * tau**2, qd + acc * tau,
                                          acc)
                self._apply_push(t0 + tau)
                pb.stepSimulation(physicsClientId=c)
                self._joint_cache = None
        self._step += 1
        t = self.t
        if self._moving_obstacles:
            for oid, center in zip(self._obstacle_ids, sc.obstacles.at(t)):
                pb.resetBasePositionAndOrientation(oid, center.tolist(), [0, 0, 0, 1],
                                                   physicsClientId=c)
        if self._moving_goal:
            pb.resetBasePositionAndOrientation(self._goal_marker, self.goal_position(t).tolist(),
                                               [0, 0, 0, 1], physicsClientId=c)
        return self.observe()

    def _apply_impedance(self, q_d: np.ndarray, qd_d: np.ndarray, acc: np.ndarray) -> None:
        """One substep of the joint impedance controller (module docstring)."""
        c = self._client
        q, qd = self._joint_state()
        cfg = self.config
        if cfg.feedforward:
            base = pb.calculateInverseDynamics(self._robot, q.tolist(), qd.tolist(),
                                               acc.tolist(), physicsClientId=c)
        else:
            zeros = [0.0] * self.spec.dof
            base = pb.calculateInverseDynamics(self._robot, q.tolist(), zeros, zeros,
                                               physicsClientId=c)
        gains = self.spec.impedance
        torque = (np.asarray(base) + np.asarray(gains.stiffness) * (q_d - q)
                  + np.asarray(gains.damping) * (qd_d - qd))
        limit = np.asarray(gains.torque_limit, dtype=float)
        pb.setJointMotorControlArray(self._robot, self._joint_idx, pb.TORQUE_CONTROL,
                                     forces=np.clip(torque, -limit, limit).tolist(),
                                     physicsClientId=c)

    def _apply_push(self, t: float) -> None:
        """The push's force on its link if t [s] is inside [onset, onset + duration)."""
        dist = self.disturbance
        if dist.kind != "push" or not dist.onset - 1e-9 <= t < dist.onset + dist.duration - 1e-9:
            return
        c = self._client
        if self._push_link >= 0:
            where = pb.getLinkState(self._robot, self._push_link, physicsClientId=c)[4]
        else:
            where = pb.getBasePositionAndOrientation(self._robot, physicsClientId=c)[0]
        pb.applyExternalForce(self._robot, self._push_link, list(map(float, dist.force)), where,
                              pb.WORLD_FRAME, physicsClientId=c)

    def _joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, q̇) now, copies; read from PyBullet once per physics state (cached until the next
        ``stepSimulation``: ``step`` reads the state that the last observation already read)."""
        if self._joint_cache is None:
            states = pb.getJointStates(self._robot, self._joint_idx,
                                       physicsClientId=self._client)
            self._joint_cache = (np.array([s[0] for s in states]),
                                 np.array([s[1] for s in states]))
        q, qd = self._joint_cache
        return q.copy(), qd.copy()

    def obstacle_centers(self, t: float | None = None) -> np.ndarray:
        """True obstacle centres (n, 3) [m] at time t (default: now): what decides contacts."""
        return self._scenario.obstacles.at(self.t if t is None else t)

    def _sensed_obstacles(self, t: float) -> np.ndarray:
        """Obstacle centres as the controller sees them (noisy, sampled, held) at time t [s]."""
        dist = self.disturbance
        truth = self._scenario.obstacles.at(t)
        if dist.kind != "obstacle_noise" or not len(truth):
            return truth
        sample = math.floor(t * dist.sensor_rate + 1e-9)
        if sample != self._sensor_sample:
            t_s = sample / dist.sensor_rate
            self._sensed_centers = (self._scenario.obstacles.at(t_s)
                                    + self._noise_rng.normal(0.0, dist.noise_std, truth.shape))
            self._sensor_sample = sample
        return self._sensed_centers

    def observe(self) -> Observation:
        """The current state as an :class:`Observation` (simulator truth, except the obstacle
        centres under ``obstacle_noise``)."""
        sc = self._scenario
        q, qd = self._joint_state()
        t = self.t
        return Observation(
            t=t,
            step=self._step,
            q=q,
            qd=qd,
            obstacle_centers=self._sensed_obstacles(t),
            obstacle_radii=sc.obstacles.radii,
            obstacle_velocities=sc.obstacles.velocities,
            goal_position=self.goal_position(t),
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
        states = pb.getLinkStates(self._robot, self._movable_links,
                                  computeForwardKinematics=True, physicsClientId=self._client)
        pos, quat = self._base_pose[0].copy(), self._base_pose[1].copy()  # base: the origin
        if self._any_movable:
            pos[self._movable_rows] = [s[4] for s in states]
            quat[self._movable_rows] = [s[5] for s in states]
        return pos, quat

    def body_sphere_centers(self, link_pos: np.ndarray, link_quat: np.ndarray) -> np.ndarray:
        """Collision-sphere centres (k, 3) [m] from link poses (as returned by link_poses):
        ``c_i = p_l + R(q_l) o_i`` for sphere i on link l with offset o_i, R(q) computed as
        Bullet computes it (:func:`bullet_rotation_matrices`)."""
        centers = link_pos[self._sphere_link]  # fancy indexing: a new array
        if len(self._offset_spheres):
            rot = bullet_rotation_matrices(link_quat[self._offset_links])
            centers[self._offset_spheres] += np.matmul(
                rot, self._sphere_offset[self._offset_spheres, :, None])[:, :, 0]
        return centers

    def contacts(self, sphere_centers: np.ndarray) -> Contacts:
        """Clearance of the body spheres and PyBullet contacts of the robot at this instant.

        A contact is a PyBullet contact point whose signed distance (``contactDistance``:
        positive for separation, negative for penetration) is ≤ 0: Bullet also reports the
        pairs closer than its contact margin that do not touch (a link 0.4 mm from an obstacle
        all along its way round it), which are not contacts."""
        sc = self._scenario
        c = self._client
        if len(sc.obstacles):
            # static obstacles: o + t·0 = o, so their centres are used as they are
            obst = sc.obstacles.at(self.t) if self._moving_obstacles else sc.obstacles.centers
            diff = sphere_centers[:, None, :] - obst[None, :, :]
            diff *= diff  # ‖·‖ as np.linalg.norm(axis=-1) computes it, without its wrapper
            gaps = (np.sqrt(np.add.reduce(diff, axis=-1))
                    - self._sphere_radii[:, None] - sc.obstacles.radii[None, :])
            clearance = float(np.minimum.reduce(gaps, axis=None))
        else:
            clearance = math.inf
        obstacle_set = self._obstacle_set
        obstacle_contact = False
        ground_contact = False
        for cp in pb.getContactPoints(bodyA=self._robot, physicsClientId=c):
            other, link, distance = cp[2], cp[3], cp[8]
            if distance > 0.0:
                continue
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

"""Robot kinematics on pinocchio: FK, frame Jacobians, J̇q̇ and collision-sphere kinematics.

One :class:`Kinematics` object wraps a pinocchio model built from the robot's URDF (the same
file the simulator loads). Its single per-step call, :meth:`Kinematics.evaluate`, runs the
forward kinematics once and returns everything a controller needs as a frozen
:class:`KinematicState`:

- end-effector position p [m], rotation R, quaternion (x, y, z, w);
- the 6×dof frame Jacobian ``J = [J_v; J_ω]`` in the world-aligned frame at the end-effector origin,
  so that ``[ṗ; ω] = J q̇``;
- the curvature term ``J̇ q̇`` [m/s², rad/s²] (pinocchio's classical frame acceleration at q̈ = 0),
  so that ``[p̈; ω̇] = J q̈ + J̇ q̇``;
- for every collision sphere i: centre c_i [m], Jacobian ``J_i = ∂c_i/∂q`` (3×dof) and ``J̇_i q̇``,
  batched as arrays of shape (k, 3), (k, 3, dof), (k, 3).

numpy and pinocchio; the frames' Jacobians and J̇q̇ compiled by numba where it is installed
(:mod:`tamedpuma.robot.point_motion`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields, replace

import numpy as np
import pinocchio as pin

from tamedpuma.errors import ConfigError
from tamedpuma.robot import point_motion


def default_urdf_path() -> str:
    """Path of ``pybullet_data``'s ``kuka_iiwa/model.urdf`` (kinematically the authors' iiwa14)."""
    import pybullet_data  # data files only; no simulator import

    return os.path.join(pybullet_data.getDataPath(), "kuka_iiwa", "model.urdf")


def resolve_urdf(path: str | None) -> str:
    """``robot.urdf``: null = the iiwa of pybullet_data; an existing path as given (user home
    expanded); otherwise a path inside ``pybullet_data`` (e.g. ``franka_panda/panda.urdf``)."""
    if not path:
        return default_urdf_path()
    expanded = os.path.expanduser(str(path))
    if os.path.isabs(expanded) or os.path.isfile(expanded):
        return expanded
    import pybullet_data

    inside = os.path.join(pybullet_data.getDataPath(), expanded)
    return inside if os.path.isfile(inside) else expanded


@dataclass(frozen=True)
class BodySphere:
    """A collision sphere rigidly attached to a link: centre = link origin + R_link · offset [m].
    One entry of ``robot.spheres`` (the schema, ``tamedpuma/app/schema.py``, takes its fields and
    the offset's default from here)."""

    link: str
    radius: float
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        offset = tuple(float(v) for v in self.offset)
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"robot.spheres.radius must be a finite number > 0, "
                             f"got {self.radius!r}")
        if len(offset) != 3 or not all(np.isfinite(offset)):
            raise ValueError(f"robot.spheres.offset must be 3 finite numbers [m], got {offset}")
        object.__setattr__(self, "link", str(self.link))
        object.__setattr__(self, "radius", float(self.radius))
        object.__setattr__(self, "offset", offset)


@dataclass(frozen=True)
class JointImpedance:
    """The robot's joint impedance controller (``robot.impedance``; the simulator's
    ``sim.control: impedance``): per joint the stiffness K [N·m/rad], the damping D [N·m·s/rad]
    and the torque limit [N·m] the commanded torque is clipped to."""

    stiffness: tuple[float, ...]
    damping: tuple[float, ...]
    torque_limit: tuple[float, ...]

    def __post_init__(self):
        for key in ("stiffness", "damping", "torque_limit"):
            values = tuple(float(v) for v in getattr(self, key))
            if not all(np.isfinite(values)) or min(values, default=0.0) < 0:
                raise ValueError(f"robot.impedance.{key} must be finite numbers >= 0, "
                                 f"got {values}")
            object.__setattr__(self, key, values)
        if not len(self.stiffness) == len(self.damping) == len(self.torque_limit):
            raise ValueError("robot.impedance: stiffness, damping and torque_limit need one "
                             "value per joint each")


@dataclass(frozen=True)
class RobotSpec:
    """Robot data from config.

    q_min, q_max: joint position limits [rad]; qd_max: joint speed limits [rad/s];
    ee_link: end-effector frame (its origin is the task point); spheres: collision spheres, the
    body of the paper's collision check (the simulator's clearance) and of every controller;
    guard_spheres: more spheres only the controllers keep clear of obstacles, covering the stretches
    of link between ``spheres`` (:meth:`controller_body`); link_names: the links whose poses are
    logged (base first).
    """

    urdf_path: str
    joint_names: tuple[str, ...]
    link_names: tuple[str, ...]
    ee_link: str
    q_min: np.ndarray
    q_max: np.ndarray
    qd_max: np.ndarray
    spheres: tuple[BodySphere, ...]
    home: tuple[float, ...] | None = None  # default start [rad] (a scenario with q0: null)
    guard_spheres: tuple[BodySphere, ...] = ()
    impedance: JointImpedance | None = None  # the joint impedance controller's gains (None:
    #                                          the robot config gives none)

    def __post_init__(self):
        n = len(self.joint_names)
        if self.home is not None and len(self.home) != n:
            raise ConfigError(f"robot.home must be {n} joint angles, got {list(self.home)}")
        for name in ("q_min", "q_max", "qd_max"):
            arr = np.array(getattr(self, name), dtype=float)
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ConfigError(f"robot.{name} must be {n} finite numbers, got {arr.tolist()}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if np.any(self.q_min >= self.q_max):
            raise ConfigError("robot.q_min must be below robot.q_max for every joint")
        if np.any(self.qd_max <= 0):
            raise ConfigError("robot.qd_max must be positive")

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    @property
    def sphere_radii(self) -> np.ndarray:
        return np.array([s.radius for s in self.spheres])

    def controller_body(self) -> RobotSpec:
        """The robot as the controllers see it: ``spheres`` followed by ``guard_spheres`` (the
        same spec when there are none). The simulator, the recorders and the success criteria
        keep ``spheres`` alone, so the paper's collision check is the authors' five spheres
        whatever the controllers avoid with."""
        if not self.guard_spheres:
            return self
        return replace(self, spheres=self.spheres + self.guard_spheres, guard_spheres=())


def _body_spheres(entries, key: str) -> tuple[BodySphere, ...]:
    """``robot.<key>`` (typed entries with :class:`BodySphere`'s attributes) as
    :class:`BodySphere` s; a bad entry is a one-line :class:`ConfigError`."""
    try:
        return tuple(BodySphere(**{f.name: getattr(s, f.name) for f in fields(BodySphere)})
                     for s in entries)
    except (AttributeError, TypeError, ValueError) as exc:
        raise ConfigError(f"robot.{key}: {exc}") from None


def robot_spec_from_config(cfg) -> RobotSpec:
    """Build a :class:`RobotSpec` from the typed ``robot`` config (the schema's ``RobotSchema``,
    e.g. :func:`tamedpuma.app.config.robot_config`; read by attribute)."""
    urdf = resolve_urdf(cfg.urdf)
    if not os.path.isfile(urdf):
        raise ConfigError(f"robot.urdf: no such file: {urdf}")
    spheres = _body_spheres(cfg.spheres, "spheres")
    guards = _body_spheres(cfg.guard_spheres or (), "guard_spheres")
    impedance = cfg.impedance
    return RobotSpec(
        urdf_path=urdf,
        joint_names=tuple(cfg.joint_names),
        link_names=tuple(cfg.link_names),
        ee_link=str(cfg.ee_link),
        q_min=np.array(cfg.q_min, dtype=float),
        q_max=np.array(cfg.q_max, dtype=float),
        qd_max=np.array(cfg.qd_max, dtype=float),
        spheres=spheres,
        home=None if cfg.home is None else tuple(float(v) for v in cfg.home),
        guard_spheres=guards,
        impedance=None if impedance is None else JointImpedance(
            **{f.name: tuple(getattr(impedance, f.name)) for f in fields(JointImpedance)}),
    )


@dataclass(frozen=True, slots=True)
class KinematicState:
    """Kinematics at one (q, q̇); world frame, metres and radians.

    ee_position (3,); ee_rotation (3, 3); ee_quaternion (4,) (x, y, z, w);
    ee_jacobian (6, dof) rows [v; ω]; ee_jdqd (6,) = J̇q̇;
    sphere_centers (k, 3); sphere_jacobians (k, 3, dof); sphere_jdqd (k, 3); sphere_radii (k,).
    """

    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_quaternion: np.ndarray
    ee_jacobian: np.ndarray
    ee_jdqd: np.ndarray
    sphere_centers: np.ndarray
    sphere_jacobians: np.ndarray
    sphere_jdqd: np.ndarray
    sphere_radii: np.ndarray


_WORLD = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class Kinematics:
    """Pinocchio model of a :class:`RobotSpec`; collision spheres are extra operational frames.

    URDF joints not in ``spec.joint_names`` (a gripper's fingers) are locked at their neutral
    value, as the simulator leaves them."""

    def __init__(self, spec: RobotSpec):
        self.spec = spec
        try:
            model = pin.buildModelFromUrdf(spec.urdf_path)
        except Exception as exc:  # pinocchio raises plain exceptions for bad files
            raise ConfigError(f"cannot load URDF {spec.urdf_path}: {exc}") from exc
        names = [model.names[i] for i in range(1, model.njoints)]
        missing = [n for n in spec.joint_names if n not in names]
        if missing:
            raise ConfigError(f"robot.joint_names {missing} are not joints of URDF {names}")
        extra = [n for n in names if n not in spec.joint_names]
        if extra:  # e.g. the Panda's two finger joints: locked at their neutral value (closed)
            model = pin.buildReducedModel(model, [model.getJointId(n) for n in extra],
                                          pin.neutral(model))
            names = [model.names[i] for i in range(1, model.njoints)]
        if tuple(names) != spec.joint_names:
            raise ConfigError(f"robot.joint_names {spec.joint_names} do not match the URDF's "
                              f"order {names}")
        self.link_ids = tuple(self._frame_id(model, n) for n in spec.link_names)
        self.ee_id = self._frame_id(model, spec.ee_link)
        sphere_ids = []
        for i, s in enumerate(spec.spheres):
            parent = model.frames[self._frame_id(model, s.link)]
            placement = parent.placement * pin.SE3(np.eye(3), np.array(s.offset, dtype=float))
            frame = pin.Frame(f"body_sphere_{i}", parent.parentJoint, placement,
                              pin.FrameType.OP_FRAME)
            sphere_ids.append(model.addFrame(frame, False))
        self.sphere_ids = tuple(sphere_ids)
        self.model = model
        self._data = model.createData()
        self._pending: tuple | None = None  # (q, q̇) of evaluate's pinocchio pass, run when read
        self._zeros = np.zeros(model.nv)
        self._link_ids: dict[str, int] = {}  # link_position_jacobian's frame ids, by name
        self._radii = spec.sphere_radii
        self._radii.setflags(write=False)
        self._tables: dict[tuple, tuple] = {}  # frame ids -> their point_motion table
        self._chain = _revolute_chain(model)
        # the chain's placements, Jacobians and J̇q̇ in compiled calls (None: pinocchio's calls)
        self._fast = point_motion.compiled() if self._chain is not None else None
        self._ee_table = self._table((self.ee_id,))
        self._sphere_table = self._table(self.sphere_ids)
        self._state: tuple | None = None  # the last evaluate's joint state and q̇ (compiled)

    @property
    def data(self):
        """pinocchio's data, holding the last pass at (q, q̇): :meth:`evaluate`'s own
        (placements, joint Jacobians, accelerations at q̈ = 0), run here when first read after
        it rather than in every step, or the pass of a later call that runs one
        (:meth:`ee_pose_jacobian`, :meth:`placements`, :meth:`link_poses`)."""
        if self._pending is not None:
            q, qd = self._pending
            self._pending = None
            _pinocchio_pass(self.model, self._data, q, qd, self._zeros)
        return self._data

    def _fresh_data(self):
        """pinocchio's data for a pass that replaces the pending one of :meth:`evaluate`."""
        self._pending = None
        return self._data

    @staticmethod
    def _frame_id(model, name: str) -> int:
        if not model.existFrame(name):
            raise ConfigError(f"link {name!r} is not in the URDF")
        return model.getFrameId(name)

    def _vector(self, v) -> np.ndarray:
        """v as a fresh, writable float vector of the model's size (the compiled functions'
        argument type; they do not check bounds, so a wrong size is a ValueError here)."""
        if type(v) is np.ndarray and v.dtype == np.float64:  # (a copy: np.array's, cheaper)
            out = v.copy()
        else:
            out = np.array(v, dtype=float)
        if out.shape != (self.model.nv,):
            raise ValueError(f"expected a vector of {self.model.nv} joint values, got shape "
                             f"{out.shape}")
        return out

    def _table(self, frame_ids) -> tuple:
        """The frames as :func:`point_motion.frame_motion` takes them: parent joint indices
        (F,) (−1: the base), placements in their joints (F, 3, 3), (F, 3), and the joints that
        move each (F, n) bool."""
        ids = tuple(frame_ids)
        table = self._tables.get(ids)
        if table is None:
            model = self.model
            F = len(ids)
            parents, Rf, pf = np.empty(F, np.int64), np.empty((F, 3, 3)), np.empty((F, 3))
            support = np.zeros((F, model.nv), dtype=np.bool_)
            for f, fid in enumerate(ids):
                frame = model.frames[fid]
                parents[f] = frame.parentJoint - 1
                Rf[f], pf[f] = frame.placement.rotation, frame.placement.translation
                for j in model.supports[frame.parentJoint]:
                    if j > 0:
                        joint = model.joints[j]
                        support[f, joint.idx_v:joint.idx_v + joint.nv] = True
            table = self._tables[ids] = (parents, Rf, pf, support)
        return table

    def _frames(self, q: np.ndarray, qd: np.ndarray, table: tuple, rows: int):
        """(rotations, origins, Jacobians, J̇q̇) of the frames of ``table`` at (q, q̇), compiled;
        the joint state is kept for :meth:`frame_motion` and :meth:`link_position_jacobian`."""
        fast = self._fast
        state = fast["joint_motion"](q, qd, *self._chain)
        self._state = (state, qd)
        return fast["frame_motion"](state, qd, *table, rows)

    def evaluate(self, q: np.ndarray, qd: np.ndarray) -> KinematicState:
        """All controller kinematics at (q [rad], q̇ [rad/s]) from one forward pass.

        Compiled (:mod:`tamedpuma.robot.point_motion`, where numba is installed): one pass over
        the joints, then the end effector's and the body spheres' placements, Jacobians and
        curvature terms J̇q̇, in one call. Otherwise one pinocchio call per frame and
        quantity: the same numbers to rounding. Either way :attr:`data` (pinocchio's) holds its
        own pass at (q, q̇) afterwards (placements, joint Jacobians, accelerations at q̈ = 0),
        for code that reads the model's frames; compiled, that pass runs when ``data`` is first
        read. Every array is fresh.
        """
        q, qd = self._vector(q), self._vector(qd)
        if self._fast is None:
            return self._evaluate_per_frame(q, qd)
        fast = self._fast
        S, R, p, J, acc, centers, jacobians, jdqd, quat = fast["chain_evaluate"](
            q, qd, *self._chain, *self._ee_table, *self._sphere_table)
        self._state = (S, qd)
        # pinocchio's own pass at (q, q̇) for whoever reads the model's frames after evaluate
        # (a method plugin's, e.g. pink's Configuration): run when ``data`` is read, so a step
        # that never reads it does not pay for it (q and q̇ are this call's own copies)
        self._pending = (q, qd)
        return KinematicState(
            ee_position=p[0],
            ee_rotation=R[0],
            ee_quaternion=quat,
            ee_jacobian=J[0],
            ee_jdqd=acc[0],  # [linear; angular]
            sphere_centers=centers,
            sphere_jacobians=jacobians,
            sphere_jdqd=jdqd,
            sphere_radii=self._radii,
        )

    def _evaluate_per_frame(self, q: np.ndarray, qd: np.ndarray) -> KinematicState:
        """:meth:`evaluate` by pinocchio: its pass, then per frame the placement, the Jacobian
        and the classical acceleration (where numba is missing)."""
        model, data = self.model, self._fresh_data()
        _pinocchio_pass(model, data, q, qd, self._zeros)
        oMf, ids, nv = data.oMf, self.sphere_ids, model.nv
        jacobian, acceleration = pin.getFrameJacobian, pin.getFrameClassicalAcceleration
        ee = oMf[self.ee_id]
        pose = pin.SE3ToXYZQUAT(ee)  # fresh (7,): position, quaternion (x, y, z, w)
        centers, jacobians = np.empty((len(ids), 3)), np.empty((len(ids), 3, nv))
        jdqd = np.empty((len(ids), 3))
        for s, i in enumerate(ids):  # filled in place: no lists of arrays to stack
            centers[s] = oMf[i].translation
            jacobians[s] = jacobian(model, data, i, _WORLD)[:3]
            jdqd[s] = acceleration(model, data, i, _WORLD).linear
        return KinematicState(
            ee_position=pose[:3],
            ee_rotation=ee.rotation.copy(),
            ee_quaternion=pose[3:],
            ee_jacobian=jacobian(model, data, self.ee_id, _WORLD),
            ee_jdqd=acceleration(model, data, self.ee_id, _WORLD).vector,  # [linear; angular]
            sphere_centers=centers,
            sphere_jacobians=jacobians,
            sphere_jdqd=jdqd,
            sphere_radii=self._radii,
        )

    def frame_placements(self, frame_ids) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (k, 3, 3) and origins (k, 3) [m] of the frames at the q of the last
        :meth:`evaluate` call (no new forward pass): the numbers of its own frames."""
        ids = tuple(frame_ids)
        if self._fast is None:
            oMf = self.data.oMf
            R, p = np.empty((len(ids), 3, 3)), np.empty((len(ids), 3))
            for n, fid in enumerate(ids):
                R[n], p[n] = oMf[fid].rotation, oMf[fid].translation
            return R, p
        state, qd = self._state
        R, p, _, _ = self._fast["frame_motion"](state, qd, *self._table(ids), 0)
        return R, p

    def chain_state(self, frame_ids) -> tuple | None:
        """The compiled chain's state at the last :meth:`evaluate` and the frames' table, as
        :func:`~tamedpuma.robot.point_motion.frame_motion` takes them: ``(S, q̇, parents, R_f,
        p_f, support)``; None where the kinematics is pinocchio's (no compiled chain)."""
        if self._fast is None or self._state is None:
            return None
        state, qd = self._state
        return (state, qd, *self._table(tuple(frame_ids)))

    def frame_motion(self, frame_ids) -> tuple[np.ndarray, np.ndarray]:
        """World-aligned Jacobians (k, 6, n) ``[v; ω]`` of the frames' origins and their
        classical accelerations at q̈ = 0, J̇q̇ (k, 6) [m/s², rad/s²], at the (q, q̇) of the last
        :meth:`evaluate` call (no new forward pass): the arithmetic of its end effector."""
        ids = tuple(frame_ids)
        if self._fast is None:
            model, data = self.model, self.data
            J, acc = np.empty((len(ids), 6, model.nv)), np.empty((len(ids), 6))
            for n, fid in enumerate(ids):
                J[n] = pin.getFrameJacobian(model, data, fid, _WORLD)
                acc[n] = pin.getFrameClassicalAcceleration(model, data, fid, _WORLD).vector
            return J, acc
        state, qd = self._state
        _, _, J, acc = self._fast["frame_motion"](state, qd, *self._table(ids), 6)
        return J, acc

    def ee_pose_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """End-effector position (3,) [m], rotation (3, 3) and world-aligned Jacobian (6, n) at
        q, fresh arrays: the numbers :meth:`evaluate` gives as ``ee_position``,
        ``ee_rotation`` and ``ee_jacobian`` (at any q̇), bit for bit, without the body spheres
        (what an IK iteration needs). Like :meth:`evaluate` it leaves the placements of q for
        :meth:`link_position_jacobian`, :meth:`frame_placements` and :meth:`frame_motion`
        (at q̇ = 0)."""
        q = self._vector(q)
        if self._fast is None:
            model, data = self.model, self._fresh_data()
            pin.forwardKinematics(model, data, q)
            pin.computeJointJacobians(model, data)  # from the placements just computed
            ee = pin.updateFramePlacement(model, data, self.ee_id)
            pose = pin.SE3ToXYZQUAT(ee)  # fresh, as evaluate's ee_position
            return (pose[:3], ee.rotation.copy(),
                    pin.getFrameJacobian(model, data, self.ee_id, _WORLD))
        data = self._fresh_data()  # pinocchio's data too, as evaluate
        pin.forwardKinematics(self.model, data, q)
        pin.computeJointJacobians(self.model, data)
        R, p, J, _ = self._frames(q, np.zeros(self.model.nv), self._ee_table, 6)
        return p[0], R[0], J[0]

    def link_chain_state(self, link: str) -> tuple | None:
        """:meth:`chain_state` of the frame of ``link`` (the compiled chain's state at the last
        :meth:`evaluate` and the frame's table); None where the kinematics is pinocchio's."""
        fid = self._link_ids.get(link)
        if fid is None:
            fid = self._link_ids[link] = self._frame_id(self.model, link)
        return self.chain_state((fid,))

    def link_position_jacobian(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """Origin (3,) [m] and its 3×n position Jacobian of ``link`` at the q of the last
        :meth:`evaluate` call (no new forward pass)."""
        fid = self._link_ids.get(link)
        if fid is None:
            fid = self._link_ids[link] = self._frame_id(self.model, link)
        if self._fast is None:
            jac = pin.getFrameJacobian(self.model, self.data, fid, _WORLD)[:3]
            return self.data.oMf[fid].translation.copy(), np.array(jac)
        state, qd = self._state
        _, p, J, _ = self._fast["frame_motion"](state, qd, *self._table((fid,)), 3)
        return p[0], J[0]

    def placements(self, q: np.ndarray, frame_ids) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (k, 3, 3) and origins (k, 3) [m] of the frames at q: the numbers of
        :meth:`evaluate`'s frames (compiled, or pinocchio's placement pass)."""
        q = self._vector(q)
        data = self._fresh_data()
        if self._fast is None:
            pin.framesForwardKinematics(self.model, data, q)
            oMf = data.oMf
            return (np.array([oMf[i].rotation for i in frame_ids]).reshape(-1, 3, 3),
                    np.array([oMf[i].translation for i in frame_ids]).reshape(-1, 3))
        pin.framesForwardKinematics(self.model, data, q)  # pinocchio's data too
        R, p, _, _ = self._frames(q, np.zeros(self.model.nv), self._table(frame_ids), 0)
        return R, p

    def _quaternion(self, R: np.ndarray) -> np.ndarray:
        """(x, y, z, w) of a rotation matrix, as :meth:`evaluate`'s ``ee_quaternion``."""
        if self._fast is None:
            return pin.Quaternion(R).coeffs().copy()
        return self._fast["matrix_to_quat_eigen"](np.ascontiguousarray(R))

    def link_poses(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Poses of ``spec.link_names`` at q: positions (L, 3) [m], quaternions (L, 4) (x,y,z,w)."""
        R, p = self.placements(q, self.link_ids)
        return p, np.array([self._quaternion(r) for r in R]).reshape(-1, 4)

    def ee_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """End-effector position (3,) [m] and quaternion (4,) (x, y, z, w) at q."""
        R, p = self.placements(q, (self.ee_id,))
        return p[0], self._quaternion(R[0])

    @property
    def sphere_radii(self) -> np.ndarray:
        """Body-sphere radii (k,) [m], read-only (the spec's, built once)."""
        return self._radii

    def ee_frame(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """End-effector position (3,) [m] and rotation (3, 3) at q, fresh arrays: the
        placement pass only (the same numbers as :meth:`evaluate`'s ``ee_position`` and
        ``ee_rotation``, without its Jacobians and accelerations)."""
        R, p = self.placements(q, (self.ee_id,))
        return p[0], R[0]

    def sphere_centers(self, q: np.ndarray) -> np.ndarray:
        """Collision-sphere centres at q: (k, 3) [m]."""
        return self.placements(q, self.sphere_ids)[1]


#: pinocchio's revolute joint models and their axes in the joint frame
_AXES = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0),
         "JointModelRZ": (0.0, 0.0, 1.0)}


def _pinocchio_pass(model, data, q: np.ndarray, qd: np.ndarray, zeros: np.ndarray) -> None:
    """pinocchio's pass at (q, q̇) into data: placements, joint Jacobians, frame placements and
    the accelerations at q̈ = 0."""
    pin.forwardKinematics(model, data, q, qd, zeros)
    pin.computeJointJacobians(model, data)  # from the placements just computed
    pin.updateFramePlacements(model, data)


def _revolute_chain(model) -> tuple | None:
    """The joints as :func:`point_motion.joint_motion` takes them (placements from the parent
    joints (n, 3, 3), (n, 3), unit axes (n, 3), parent indices (n,), −1: the base), or None
    where a joint is not a one-degree-of-freedom revolute joint in configuration order
    (pinocchio's calls answer then)."""
    n = model.njoints - 1
    R0, p0, axes = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3))
    parents = np.empty(n, np.int64)
    for j in range(1, model.njoints):
        joint = model.joints[j]
        name = joint.shortname()
        if name == "JointModelRevoluteUnaligned":
            axis = np.asarray(joint.extract().axis, dtype=float)
        elif name in _AXES:
            axis = np.array(_AXES[name])
        else:
            return None
        if joint.nq != 1 or joint.nv != 1 or joint.idx_q != j - 1 or joint.idx_v != j - 1:
            return None
        placement = model.jointPlacements[j]
        R0[j - 1], p0[j - 1] = placement.rotation, placement.translation
        axes[j - 1] = axis / np.linalg.norm(axis)
        parents[j - 1] = model.parents[j] - 1
    return R0, p0, axes, parents

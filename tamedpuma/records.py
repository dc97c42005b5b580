"""What a recorder receives: one :class:`RunInfo` per episode, one :class:`StepRecord` per step.

numpy only. Units: metres, radians, seconds. Quaternions are (x, y, z, w) in the world frame.
Arrays are stored as float64 numpy arrays (shape-checked, not copied when already float64).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

_F8 = np.dtype(float)


def _array(value, shape: tuple[int | None, ...], name: str) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (None = any length); ValueError otherwise."""
    arr = value if type(value) is np.ndarray and value.dtype is _F8 else np.asarray(
        value, dtype=float)  # (the control loop's arrays: no conversion call)
    got = arr.shape
    if got == shape:  # a shape given in full: one comparison
        return arr
    if len(got) != len(shape):
        raise ValueError(f"{name} must have shape {shape}, got {got}")
    for s, n in zip(shape, got):
        if s is not None and s != n:
            raise ValueError(f"{name} must have shape {shape}, got {got}")
    return arr


@dataclass(frozen=True)
class RunInfo:
    """Static description of one recorded episode.

    run_id: unique id of the run; method, task, scenario_name, seed: what was run;
    config_yaml: the resolved Hydra config (YAML text); urdf_path: robot URDF file;
    joint_names: the n actuated joints, in the order of every :class:`StepRecord`'s q (the
    robot config's, e.g. ``lbr_iiwa_joint_1..7``); link_names: the L links whose poses each
    :class:`StepRecord` carries (e.g. ``lbr_iiwa_link_0..7``); both required: the recording
    names what the robot has, never a default robot's;
    body_sphere_radii: (k,) collision-sphere radii on the robot body [m]; dt: control period [s];
    velocity_limits: (n,) joint speed limits [rad/s] (empty: unknown, replays plot raw speeds).
    model: the trained model the method used (``model_path``, ``model_sha256``, ``model_origin``,
    ``model_data``, ``model_data_source``, ``model_data_sha256``; empty for methods without one).
    """

    run_id: str
    method: str
    task: str
    scenario_name: str
    seed: int
    config_yaml: str
    urdf_path: str
    dt: float
    joint_names: tuple[str, ...]
    link_names: tuple[str, ...]
    body_sphere_radii: np.ndarray = field(default_factory=lambda: np.zeros(0))
    velocity_limits: np.ndarray = field(default_factory=lambda: np.zeros(0))
    model: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "link_names", tuple(self.link_names))
        radii = _array(np.ravel(self.body_sphere_radii), (None,), "body_sphere_radii")
        object.__setattr__(self, "body_sphere_radii", radii)
        limits = _array(np.ravel(self.velocity_limits), (None,), "velocity_limits")
        if len(limits) not in (0, len(self.joint_names)):
            raise ValueError(f"velocity_limits must be empty or have one value per joint "
                             f"({len(self.joint_names)}), got {len(limits)}")
        object.__setattr__(self, "velocity_limits", limits)
        if not self.joint_names:
            raise ValueError("joint_names must name at least one joint")
        if not self.dt > 0:
            raise ValueError(f"dt must be positive, got {self.dt}")

    def metadata(self) -> dict[str, str]:
        """The fields as a flat string map (MCAP metadata); config_yaml is left out (stored apart).

        Tuples and arrays are JSON lists.
        """
        return {
            "run_id": self.run_id,
            "method": self.method,
            "task": self.task,
            "scenario_name": self.scenario_name,
            "seed": str(int(self.seed)),
            "urdf_path": str(self.urdf_path),
            "joint_names": json.dumps(list(self.joint_names)),
            "link_names": json.dumps(list(self.link_names)),
            "body_sphere_radii": json.dumps([float(r) for r in self.body_sphere_radii]),
            "dt": repr(float(self.dt)),
            "velocity_limits": json.dumps([float(v) for v in self.velocity_limits]),
            **{str(k): str(v) for k, v in dict(self.model).items()},
        }


@dataclass(frozen=True)
class StepRecord:
    """Everything logged for one control step (simulator truth at the start of the step).

    step: control step index; t: simulated time [s];
    q, qd: (n,) joint positions [rad] and velocities [rad/s]; qdd_cmd: (n,) commanded joint
    acceleration [rad/s²];
    link_positions: (L, 3) [m] and link_quaternions: (L, 4) (x, y, z, w) world poses of the links
    named in :attr:`RunInfo.link_names`;
    ee_position: (3,) [m]; ee_quaternion: (4,) end-effector pose in the world frame;
    body_sphere_centers: (k, 3) [m] robot collision-sphere centres (radii in :class:`RunInfo`);
    obstacle_centers: (n, 3) [m]; obstacle_radii: (n,) [m] (n may change between steps);
    goal_position: (3,) [m]; goal_quaternion: (4,);
    scalars: name -> value (``compute_time_ms`` [ms], ``clearance_m`` [m] and the method's
    internals: energies, alpha, beta, psi, ...). Keys are constant within a run.
    """

    step: int
    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd_cmd: np.ndarray
    link_positions: np.ndarray
    link_quaternions: np.ndarray
    ee_position: np.ndarray
    ee_quaternion: np.ndarray
    body_sphere_centers: np.ndarray
    obstacle_centers: np.ndarray
    obstacle_radii: np.ndarray
    goal_position: np.ndarray
    goal_quaternion: np.ndarray
    scalars: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self):
        s = object.__setattr__
        s(self, "q", _array(self.q, (None,), "q"))
        n = len(self.q)
        s(self, "qd", _array(self.qd, (n,), "qd"))
        s(self, "qdd_cmd", _array(self.qdd_cmd, (n,), "qdd_cmd"))
        s(self, "link_positions", _array(self.link_positions, (None, 3), "link_positions"))
        n_links = len(self.link_positions)
        s(self, "link_quaternions", _array(self.link_quaternions, (n_links, 4), "link_quaternions"))
        s(self, "ee_position", _array(self.ee_position, (3,), "ee_position"))
        s(self, "ee_quaternion", _array(self.ee_quaternion, (4,), "ee_quaternion"))
        s(self, "body_sphere_centers",
          _array(_reshaped(self.body_sphere_centers, (-1, 3)), (None, 3), "body_sphere_centers"))
        s(self, "obstacle_centers",
          _array(_reshaped(self.obstacle_centers, (-1, 3)), (None, 3), "obstacle_centers"))
        n_obs = len(self.obstacle_centers)
        s(self, "obstacle_radii", _array(_reshaped(self.obstacle_radii, (-1,)), (n_obs,),
                                         "obstacle_radii"))
        s(self, "goal_position", _array(self.goal_position, (3,), "goal_position"))
        s(self, "goal_quaternion", _array(self.goal_quaternion, (4,), "goal_quaternion"))


def _reshaped(value, shape: tuple[int, ...]):
    """``np.reshape(value, shape)`` (``np.ravel`` for (-1,)), by the array's own method when
    it is one."""
    return value.reshape(shape) if type(value) is np.ndarray else np.reshape(value, shape)


class Recorder(Protocol):
    """A passive sink for one episode: ``open`` once, ``write`` every step, ``close`` once.

    ``close(complete=False, ...)`` marks an interrupted episode (Ctrl-C, SIGTERM, an error);
    ``summary`` holds the run's end result (JSON-serialisable values: success, steps, reason...).
    """

    def open(self, info: RunInfo) -> None: ...

    def write(self, rec: StepRecord) -> None: ...

    def close(self, complete: bool, summary: Mapping[str, object]) -> None: ...

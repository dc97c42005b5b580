"""The simulator's settings (PyBullet-free, so configs are checked without loading PyBullet):
:class:`SimConfig` (physics and the joint control chain) and :class:`Disturbance` (what perturbs
an episode). Used by :mod:`tamedpuma.worlds.bullet`; their defaults are the config defaults
(``tamedpuma/app/schema.py`` uses them as the ``sim`` and ``disturbance`` schemas).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SimConfig:
    """gui: open a window; substep: physics step [s]; gravity [m/s²] along −z;
    max_joint_force: motor force limit [N·m] of the velocity controller; ground: add a plane;
    control: ``velocity`` or ``impedance`` (the robot's joint impedance gains,
    ``robot.impedance``); feedforward: the impedance controller adds the inverse dynamics of the
    commanded acceleration (else gravity compensation only)."""

    gui: bool = False
    substep: float = 0.001
    gravity: float = 9.81
    max_joint_force: float = 500.0
    ground: bool = True
    control: str = "velocity"
    feedforward: bool = True

    def __post_init__(self):
        if self.control not in CONTROL_MODES:
            raise ValueError(f"sim.control must be one of {CONTROL_MODES}, got {self.control!r}")


CONTROL_MODES = ("velocity", "impedance")
DISTURBANCE_KINDS = ("none", "goal_change", "push", "obstacle_noise")


@dataclass(frozen=True)
class Disturbance:
    """What perturbs an episode (see the module docstring). name: the behaviour's name in run
    folders and tables (``impedance`` has kind ``none``); onset [s]; duration [s] (push);
    force (3,) [N] in the world frame (push); link: the pushed link (None: the robot's
    end-effector link, ``robot.ee_link``); goal_offset (3,) [m]
    (goal_change); noise_std [m] and sensor_rate [Hz] (obstacle_noise)."""

    kind: str = "none"
    name: str = ""  # the config's name (run folders, tables); the kind if empty
    onset: float = 3.0
    duration: float = 0.2
    force: tuple[float, ...] = (0.0, 0.0, 0.0)
    link: str | None = None
    goal_offset: tuple[float, ...] = (0.0, 0.0, 0.0)
    noise_std: float = 0.0
    sensor_rate: float = 30.0

    def __post_init__(self):
        if self.kind not in DISTURBANCE_KINDS:
            raise ValueError(f"disturbance.kind must be one of {DISTURBANCE_KINDS}, "
                             f"got {self.kind!r}")
        if not (self.onset >= 0 and self.duration >= 0 and self.noise_std >= 0
                and self.sensor_rate > 0):
            raise ValueError("disturbance: onset, duration and noise_std must be >= 0, "
                             "sensor_rate > 0")
        if len(self.force) != 3 or len(self.goal_offset) != 3:
            raise ValueError("disturbance.force and goal_offset must have 3 components")

    @property
    def onset_time(self) -> float | None:
        """When a discrete disturbance begins [s] (goal change, push), else None."""
        return float(self.onset) if self.kind in ("goal_change", "push") else None

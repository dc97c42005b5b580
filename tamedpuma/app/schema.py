"""Typed schemas of the fixed config groups (robot, scenario, sim, recorder and the top level).

``validate(cfg)`` merges each group into its schema with OmegaConf, so a wrong type or an unknown
key is reported with the key's name (``robot.limit_margin: Value 'abc' ... Float``). Method and
task groups are open: each method validates its own keys in its ``make``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from omegaconf import MISSING, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from tamedpuma.errors import ConfigError


@dataclass
class SphereSchema:
    link: str = MISSING
    radius: float = MISSING
    offset: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclass
class RobotSchema:
    name: str = MISSING
    urdf: Any = None
    joint_names: list[str] = MISSING
    link_names: list[str] = MISSING
    ee_link: str = MISSING
    q_min: list[float] = MISSING
    q_max: list[float] = MISSING
    qd_max: list[float] = MISSING
    limit_tolerance: float = 1e-4
    limit_margin: float = 1e-3
    spheres: list[SphereSchema] = MISSING
    home: Any = None                  # default start [rad] (scenario=default uses it)
    null_space: Any = None            # {link, target}: PUMA's "elbow up" objective
    body_model: Any = None            # {skip, merge}: for python -m tamedpuma.body_model
    body_model_tolerance: Any = None  # [m], written by python -m tamedpuma.body_model


@dataclass
class GoalSchema:
    position: Optional[list[float]] = MISSING    # null: the task's derived goal  # noqa: UP045
    quaternion: Optional[list[float]] = MISSING  # noqa: UP045
    velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclass
class ObstacleSchema:
    center: list[float] = MISSING
    radius: float = MISSING
    velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclass
class ScenarioSchema:
    name: str = MISSING
    task: Any = None  # if set, the task group must match
    q0: Any = MISSING  # joint angles [rad]; null: the robot's home; not set by generators
    goal: GoalSchema = field(default_factory=GoalSchema)
    random_seed: Any = None  # scenario=random: the generator's seed (int)
    start_kind: Any = None  # scenario=random: near_table1 | anywhere
    random: Any = None  # scenario=random: generator parameters (RandomParams)
    generator: Any = None  # scenario=from_demos: {kind: demos, ...} (worlds/demo_scenarios.py)
    obstacles: list[ObstacleSchema] = field(default_factory=list)
    dt: float = 0.02
    max_steps: int = 2000
    goal_tolerance: float = 0.05


@dataclass
class SimSchema:
    gui: bool = False
    substep: float = 0.001
    gravity: float = 9.81
    max_joint_force: float = 500.0
    ground: bool = True
    control: str = "velocity"
    stiffness: list[float] = field(default_factory=lambda: [600.0, 600.0, 300.0, 300.0, 100.0,
                                                            50.0, 20.0])
    damping: list[float] = field(default_factory=lambda: [30.0, 30.0, 15.0, 15.0, 5.0, 2.0, 0.5])
    torque_limit: list[float] = field(default_factory=lambda: [320.0, 320.0, 176.0, 176.0, 110.0,
                                                               40.0, 40.0])
    feedforward: bool = True


@dataclass
class DisturbanceSchema:
    kind: str = "none"
    name: str = ""
    onset: float = 3.0
    duration: float = 0.2
    force: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    link: str = "lbr_iiwa_link_7"
    goal_offset: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    noise_std: float = 0.0
    sensor_rate: float = 30.0


@dataclass
class RecorderSchema:
    mcap: bool = True
    rerun: bool = True
    flush_every: int = 100


@dataclass
class ClutterSchema:
    count: int = 0
    total: Any = None  # int: fill up to this many obstacles in all (overrides count)
    radius: float = 0.05
    low: list[float] = field(default_factory=lambda: [-1.2, -1.2, 0.05])
    high: list[float] = field(default_factory=lambda: [1.2, 1.2, 1.4])
    min_distance: float = 0.1


_GROUPS = {"robot": RobotSchema, "scenario": ScenarioSchema, "sim": SimSchema,
           "recorder": RecorderSchema, "clutter": ClutterSchema,
           "disturbance": DisturbanceSchema}
_TOP = {"seed": int, "output_root": str, "stop_on_success": bool, "without_obstacles": bool,
        "settle_time": (int, float)}


def validate(cfg) -> None:
    """Raise :class:`ConfigError` naming the key if a fixed group has a wrong type or key."""
    for group, schema in _GROUPS.items():
        if group not in cfg:
            continue
        try:
            OmegaConf.merge(OmegaConf.structured(schema), cfg[group])
        except OmegaConfBaseException as exc:
            key = getattr(exc, "full_key", None) or "?"
            message = str(exc).splitlines()[0]
            raise ConfigError(f"{group}.{key}: {message}") from None
    for key, kind in _TOP.items():
        if key in cfg:
            value = cfg[key]
            kinds = kind if isinstance(kind, tuple) else (kind,)
            ok = isinstance(value, kinds) and not (bool not in kinds and isinstance(value, bool))
            if not ok:
                what = " or ".join(k.__name__ for k in kinds)
                raise ConfigError(f"{key} must be {what}, got {value!r}")
    if "settle_time" in cfg and not cfg["settle_time"] >= 0:
        raise ConfigError(f"settle_time must be >= 0 s, got {cfg['settle_time']!r}")

"""The typed configuration: every config key, its type, its default and its valid range.

This module is the only place config defaults live. Settings the library owns are the library's
frozen dataclasses, used here as field types (their defaults are the defaults):
:class:`~tamedpuma.worlds.settings.SimConfig`, :class:`~tamedpuma.worlds.settings.Disturbance`,
:class:`~tamedpuma.fabrics.FabricGains`, each method's settings (``SETTINGS`` of
``tamedpuma/methods/<name>.py``, e.g. :class:`~tamedpuma.methods.cpm.CpmSettings`),
:class:`~tamedpuma.worlds.random_scenarios.RandomParams`,
:class:`~tamedpuma.worlds.demo_scenarios.DemoScenarioConfig`,
:class:`~tamedpuma.robot.kinematics.BodySphere`, and PUMA's
:class:`~tamedpuma.puma.settings.TrainConfig`, :class:`~tamedpuma.puma.settings.NetConfig`,
:class:`~tamedpuma.puma.settings.EvalConfig`. Everything else is a dataclass below. The YAML
files under ``conf/`` override these values; a YAML key the schema does not know is an error
(``tests/test_schema.py`` loads every YAML against it).

**Adding a key** is one line in one dataclass (name, type, default, and a range check in its
``__post_init__`` if it has one). A method's options are its module's ``SETTINGS`` dataclass
(typed here with ``name`` and ``label``: :data:`METHODS`; :func:`method_settings` gives the
frozen settings its ``make`` takes); a method plugin's are its own settings dataclass
(:class:`tamedpuma.methods.MethodPlugin`).

``run_config(cfg)`` and ``train_config(cfg)`` merge a composed config into the schema (wrong types
and unknown keys are :class:`ConfigError` naming the key), build the typed objects (ranges
checked in ``__post_init__``) and return them; ``build`` in the entry points works from those.
The schemas are also registered in Hydra's ConfigStore (``tamedpuma_sweep``, ``tamedpuma_train``,
``tamedpuma_method/<name>``).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import typing
from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from tamedpuma.errors import ConfigError
from tamedpuma.methods._settings import FpmSettings, PumaSettings
from tamedpuma.methods._settings import check as _check
from tamedpuma.methods._settings import finite as _finite
from tamedpuma.methods._settings import nonneg as _nonneg
from tamedpuma.methods._settings import positive as _positive
from tamedpuma.methods.cpm import CpmSettings
from tamedpuma.methods.fabrics import FabricsSettings
from tamedpuma.methods.joint_attractor import JointAttractorSettings
from tamedpuma.methods.modulation_ik import ModulationIkSettings
from tamedpuma.puma.settings import EvalConfig, NetConfig, TrainConfig
from tamedpuma.robot.kinematics import BodySphere, JointImpedance
from tamedpuma.worlds.demo_scenarios import DemoScenarioConfig
from tamedpuma.worlds.random_scenarios import START_KINDS, RandomParams
from tamedpuma.worlds.settings import Disturbance, SimConfig

# Limits that keep one run within memory and time (a value beyond them is refused, named).
MAX_EPISODE_STEPS = 200_000      # per-step logs and metrics are held in memory
MAX_EPISODE_SECONDS = 3600.0     # simulated time of one episode [s]
MAX_SUBSTEPS_PER_STEP = 1000     # physics substeps per control period (Δt / substep)
MAX_CLUTTER = 1000               # extra obstacles (the fabric is O(spheres × obstacles))
KEEP_CLEAR = ("start_goal", "path")  # what clutter is kept clear of
CLUTTER_REGIONS = ("box", "shell")  # where clutter.keep_clear=path draws its spheres
MAX_TRAIN_ITERATIONS = 1_000_000



def _with_fields_of(name: str, library: type, base: type | None = None) -> type:
    """A schema dataclass: ``base``'s fields (if any) plus every field of the frozen ``library``
    dataclass (same types and defaults, so the defaults stay the library's); ``base``'s checks
    and the library's constructor (its range checks) run on the result. Unlike the frozen
    library class it is writable, so YAML values merge into a node that a YAML file creates
    (``scenario.random: {}``)."""
    hints = typing.get_type_hints(library)
    extra = [(f.name, hints[f.name], field(default=f.default) if f.default_factory is
              dataclasses.MISSING else field(default_factory=f.default_factory))
             for f in dataclasses.fields(library)]

    def post_init(self):
        if hasattr(base, "__post_init__"):
            base.__post_init__(self)
        library(**{f.name: getattr(self, f.name) for f in dataclasses.fields(library)})

    made = dataclasses.make_dataclass(name, extra, bases=(base,) if base else (),
                                      namespace={"__post_init__": post_init})
    made.__module__ = __name__
    return made


# ----------------------------------------------------------------------------- robot, world


#: one entry of ``robot.spheres``: the fields, defaults (offset [0, 0, 0] in the link frame [m])
#: and checks of :class:`~tamedpuma.robot.kinematics.BodySphere`
SphereSchema = _with_fields_of("SphereSchema", BodySphere)


#: ``robot.impedance``: the fields and checks of
#: :class:`~tamedpuma.robot.kinematics.JointImpedance` (one value per joint each)
ImpedanceSchema = _with_fields_of("ImpedanceSchema", JointImpedance)


@dataclass
class RobotNullSpaceSchema:
    """The robot's "elbow up" point: replaces ``method.null_space``'s link and target."""

    link: str = MISSING
    target: list[float] = MISSING    # [m]

    def __post_init__(self):
        _check(len(self.target) == 3, "robot.null_space.target", "3 numbers [m]", self.target)


@dataclass
class BodyModelOptions:
    """How ``python -m tamedpuma.body_model`` fits this robot's spheres."""

    skip: list[str] | None = None    # links given no sphere; null: the first link (the fixed base)
    merge: dict[str, str] = field(default_factory=dict)  # link -> the link it is rigid with


@dataclass
class RobotSchema:
    name: str = MISSING
    urdf: str | None = None       # null: pybullet_data/kuka_iiwa/model.urdf
    joint_names: list[str] = MISSING
    link_names: list[str] = MISSING
    ee_link: str = MISSING
    q_min: list[float] = MISSING     # [rad]
    q_max: list[float] = MISSING     # [rad]
    qd_max: list[float] = MISSING    # [rad/s]
    limit_tolerance: float = 1e-4    # a start this far outside a limit is clamped [rad]
    limit_margin: float = 1e-3       # ... to this far inside [rad]
    spheres: list[SphereSchema] = MISSING
    home: list[float] | None = None   # default start [rad] (a scenario with q0: null uses it)
    guard_spheres: list[SphereSchema] = field(default_factory=list)  # the controllers' body
                                      # only: spheres over the links between ``spheres`` (not in
                                      # the paper's collision check; RobotSpec.controller_body)
    null_space: RobotNullSpaceSchema | None = None  # replaces the method's "elbow up" objective
    body_model: BodyModelOptions = field(default_factory=BodyModelOptions)
    body_model_tolerance: float | None = None  # [m], written by python -m tamedpuma.body_model
    impedance: ImpedanceSchema | None = None  # the joint impedance controller (sim.control:
    #                                           impedance; null: the robot has none)

    def __post_init__(self):
        n = len(self.joint_names)
        for key in ("q_min", "q_max", "qd_max"):
            _check(len(getattr(self, key)) == n, f"robot.{key}", f"{n} numbers (one per joint)",
                   getattr(self, key))
        _check(all(lo < hi for lo, hi in zip(self.q_min, self.q_max)), "robot.q_min",
               "below q_max for every joint", self.q_min)
        _check(all(_finite(v) and v > 0 for v in self.qd_max), "robot.qd_max",
               "finite and > 0", self.qd_max)
        if self.impedance is not None:
            for key in ("stiffness", "damping", "torque_limit"):
                value = getattr(self.impedance, key)
                _check(len(value) == n, f"robot.impedance.{key}", f"{n} numbers (one per joint)",
                       value)
        _nonneg("robot.limit_tolerance", self.limit_tolerance)
        _nonneg("robot.limit_margin", self.limit_margin)


@dataclass
class GoalSchema:
    position: list[float] | None = MISSING         # [m]; null: the task's derived goal
    quaternion: list[float] | None = MISSING       # (x, y, z, w)
    velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # [m/s]


@dataclass
class ObstacleSchema:
    center: list[float] = MISSING                  # [m]
    radius: float = MISSING                        # [m]
    velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # [m/s]

    def __post_init__(self):
        _positive("scenario.obstacles.radius", self.radius)


#: ``scenario.random`` (scenario=random): the generator's parameters, defaults and checks those of
#: :class:`~tamedpuma.worlds.random_scenarios.RandomParams`
RandomSchema = _with_fields_of("RandomSchema", RandomParams)


@dataclass
class _GeneratorKind:
    kind: str = "demos"              # the only generator: starts and obstacles from demonstrations

    def __post_init__(self):
        _check(self.kind == "demos", "scenario.generator.kind", "demos", self.kind)


#: ``scenario.generator`` (scenario=from_demos): ``kind`` and the fields, defaults and checks of
#: :class:`~tamedpuma.worlds.demo_scenarios.DemoScenarioConfig`
DemoGeneratorSchema = _with_fields_of("DemoGeneratorSchema", DemoScenarioConfig, _GeneratorKind)


@dataclass
class ScenarioSchema:
    name: str = MISSING
    task: str | None = None       # if set, the task group must match
    q0: list[float] | None = None    # start [rad]; null: the robot's home (or generated)
    goal: GoalSchema = field(default_factory=GoalSchema)
    random_seed: int | None = None   # scenario=random: the generator's seed
    start_kind: str = "near_table1"  # random / from-demos starts: near_table1 | anywhere
    random: RandomSchema | None = None  # scenario=random: generator parameters (RandomParams)
    generator: DemoGeneratorSchema | None = None  # scenario=from_demos: {kind: demos, ...}
    obstacles: list[ObstacleSchema] = field(default_factory=list)
    dt: float = 0.02                 # control period [s]
    max_steps: int = 2000            # episode length limit (40 s)
    goal_tolerance: float = 0.05     # success radius [m]

    def __post_init__(self):
        _positive("scenario.dt", self.dt)
        _check(1 <= self.max_steps <= MAX_EPISODE_STEPS, "scenario.max_steps",
               f"in [1, {MAX_EPISODE_STEPS}] (memory limit)", self.max_steps)
        _check(self.max_steps * self.dt <= MAX_EPISODE_SECONDS, "scenario.max_steps * dt",
               f"at most {MAX_EPISODE_SECONDS:g} s (time limit)", self.max_steps * self.dt)
        _positive("scenario.goal_tolerance", self.goal_tolerance)
        _check(self.start_kind in START_KINDS, "scenario.start_kind", " or ".join(START_KINDS),
               self.start_kind)


@dataclass
class SuiteSchema:
    """The frozen suite a run belongs to (set by ``conf/experiment/*.yaml``): its name and
    version, recorded in the run's summary; runs of different versions of one suite are not
    compared (``python -m tamedpuma.analysis.compare``). A change to a suite's scenarios or
    seeds is a new version."""

    name: str | None = None          # table1 | random | scaling | disturbance (null: no suite)
    version: int | None = None       # bumped whenever the suite's scenarios or seeds change

    def __post_init__(self):
        _check(self.version is None or self.version >= 1, "suite.version", "an integer >= 1",
               self.version)
        _check((self.name is None) == (self.version is None), "suite", "a name and a version "
               "together (or neither)", {"name": self.name, "version": self.version})


@dataclass
class RecorderSchema:
    mcap: bool = True                # stream to episode.mcap (Foxglove)
    rerun: bool = True               # stream to episode.rrd (Rerun)
    flush_every: int = 100           # MCAP chunk flush period [steps]

    def __post_init__(self):
        _check(self.flush_every >= 1, "recorder.flush_every", "an integer >= 1", self.flush_every)


@dataclass
class ClutterSchema:
    count: int = 0                   # seeded extra static obstacles
    total: int | None = None         # if set: add total − (the scenario's own) instead of count
    radius: float = 0.05             # [m]
    low: list[float] = field(default_factory=lambda: [-1.2, -1.2, 0.05])  # box corner [m]
    high: list[float] = field(default_factory=lambda: [1.2, 1.2, 1.4])    # box corner [m]
    min_distance: float = 0.1        # [m] clear of the start's body spheres, the EE and the goal
    keep_clear: str = "start_goal"   # start_goal | path: clear of a reference motion's swept
                                     # volume (tamedpuma/worlds/clutter.py; feasible scene)
    margin: float = 0.05             # [m] path: clearance of the reference's swept volume
    arm_radius: float = 0.15         # [m] path: the arm's meshes lie within this of its skeleton
                                     # (link axes, body-sphere centres; measured ≤ 0.133 m on the
                                     # moving iiwa links, 0.15 m on the base)
    region: str = "box"              # path: box (uniform) | shell (dense round the reference)
    shell: float = 0.3               # [m] region=shell: thickness of the shell
    reference: str = "fpm"           # path: the method whose run with the scenario's own
                                     # obstacles is the reference (tamedpuma/app/reference.py)
    reference_max_steps: int = 2000  # path: the reference run's step limit

    def __post_init__(self):
        _check(self.keep_clear in KEEP_CLEAR, "clutter.keep_clear", " or ".join(KEEP_CLEAR),
               self.keep_clear)
        _check(self.region in CLUTTER_REGIONS, "clutter.region", " or ".join(CLUTTER_REGIONS),
               self.region)
        _nonneg("clutter.margin", self.margin)
        _positive("clutter.arm_radius", self.arm_radius)
        _positive("clutter.shell", self.shell)
        _check(1 <= self.reference_max_steps <= MAX_EPISODE_STEPS, "clutter.reference_max_steps",
               f"in [1, {MAX_EPISODE_STEPS}]", self.reference_max_steps)
        for key in ("count", "total"):
            value = getattr(self, key)
            _check(value is None or 0 <= value <= MAX_CLUTTER, f"clutter.{key}",
                   f"in [0, {MAX_CLUTTER}] (the fabric's cost grows with every obstacle)", value)
        _check(_finite(self.radius) and 0 < self.radius <= 1.0, "clutter.radius",
               "in (0, 1] m", self.radius)
        _nonneg("clutter.min_distance", self.min_distance)
        _check(len(self.low) == 3 and len(self.high) == 3
               and all(_finite(a) and _finite(b) and a < b for a, b in zip(self.low, self.high)),
               "clutter.low/high", "3 finite numbers each with low < high",
               (self.low, self.high))


@dataclass
class WorkspaceSchema:
    position_low: list[float] = MISSING   # relative to the goal [m or the data's unit]
    position_high: list[float] = MISSING
    max_angle: float = 0.0                # [rad] around the goal orientation


@dataclass
class SyntheticSchema:
    kind: str | None = None          # the generator's shape (default: the task's name)
    n_demos: int = 10
    seed: int = 0
    time_law: str = "approach"       # approach (critically damped) | min_jerk

    def __post_init__(self):
        _check(1 <= self.n_demos <= 1000, "task.synthetic.n_demos", "in [1, 1000]", self.n_demos)
        _check(self.time_law in ("approach", "min_jerk"), "task.synthetic.time_law",
               "approach or min_jerk", self.time_law)


@dataclass
class WorkspaceCheckSchema:
    """Demonstrations and scenario starts checked against the task's workspace before training
    (:func:`tamedpuma.puma.pipeline.check_workspace`)."""

    action: str = "warn"             # warn | error | off
    robot: str = "iiwa14"            # the robot whose scenario starts are checked
    scenarios: Any = "auto"          # auto: every conf/scenario/<task>/*.yaml; or a list of names

    def __post_init__(self):
        _check(self.action in ("warn", "error", "off"), "task.workspace_check.action",
               "warn, error or off", self.action)


@dataclass
class TaskSchema:
    """A task: goal and demonstrations (robot tasks) or a LASA shape (2-D, mm)."""

    name: str = MISSING
    goal_position: list[float] | None = None
    goal_quaternion: list[float] | None = None   # (x, y, z, w); null for 2-D tasks
    demos: str | None = None      # null: synthetic; 'lasa'; or a folder of ee_state_*.pk
    goal_convention: str = "final_pose"
    synthetic: SyntheticSchema = field(default_factory=SyntheticSchema)
    workspace: WorkspaceSchema | None = None  # null: the demonstrations' box enlarged by
    #                                  margin (derived with derive: true)
    derive: bool = False             # goal, workspace and Δt from the data (task_from_demos)
    angle_margin: float = 0.15       # derive: added to the largest angle to the goal [rad]
    spread_limit: float = 0.5236     # derive: final orientations spreading more: medoid goal
    dt: Any = None                   # model step [s], 'auto' (from the data) or null: puma.dt
    min_dt: float = 0.02             # derive / dt auto: smallest model step [s]
    workspace_check: WorkspaceCheckSchema = field(default_factory=WorkspaceCheckSchema)
    margin: float = 0.1              # fraction of the box size added on each side
    unit: str = "mm"                 # LASA data unit
    shape: str | None = None      # LASA shape
    every: int = 10                  # LASA: keep every n-th sample
    pos_tol: float | None = None  # evaluation tolerance (non-metric data; null: 1% of the box)
    shapes: Any = "all"              # python -m tamedpuma.lasa: 'all' or a list of shapes
    grid: int = 20                   # python -m tamedpuma.lasa: grid x grid starts
    table: str = "benchmarks/lasa.md"  # python -m tamedpuma.lasa: where the table goes

    def __post_init__(self):
        _nonneg("task.margin", self.margin)
        _check(self.every >= 1, "task.every", "an integer >= 1", self.every)
        _check(1 <= self.grid <= 1000, "task.grid", "in [1, 1000]", self.grid)


# ----------------------------------------------------------------------------- methods


@dataclass
class MethodSchema:
    name: str = MISSING
    label: str | None = None      # the name its runs carry in tables (default: name)


# Each method's settings are its own frozen dataclass (``SETTINGS`` of its module, a plugin's
# ``settings``): here they gain ``name`` and ``label`` and become writable for the YAML merge.
JointAttractorMethod = _with_fields_of("JointAttractorMethod", JointAttractorSettings,
                                       MethodSchema)
PumaMethod = _with_fields_of("PumaMethod", PumaSettings, MethodSchema)
FabricsMethod = _with_fields_of("FabricsMethod", FabricsSettings, MethodSchema)
FpmMethod = _with_fields_of("FpmMethod", FpmSettings, MethodSchema)
CpmMethod = _with_fields_of("CpmMethod", CpmSettings, MethodSchema)
ModulationIkMethod = _with_fields_of("ModulationIkMethod", ModulationIkSettings, MethodSchema)

#: method name -> the dataclass of its options (a method without one cannot be configured)
METHODS: dict[str, type] = {
    "joint_attractor": JointAttractorMethod,
    "puma": PumaMethod,
    "fabrics": FabricsMethod,
    "fpm": FpmMethod,
    "cpm": CpmMethod,
    "modulation_ik": ModulationIkMethod,
}


def _plugin_schemas() -> dict[str, type]:
    """The schemas of the installed method plugins (:func:`tamedpuma.methods.plugins`): the
    plugin's settings dataclass with ``name`` and ``label``, its defaults and checks its own."""
    from tamedpuma.methods import plugins

    return {name: _with_fields_of(f"{name.title().replace('_', '')}Method", plugin.settings,
                                  MethodSchema) for name, plugin in plugins().items()}


METHODS.update(_plugin_schemas())


# ----------------------------------------------------------------------------- whole configs


@dataclass
class RunConfig:
    """One episode (``conf/sweep.yaml``): ``python -m tamedpuma.sweep``."""

    robot: RobotSchema = MISSING
    task: TaskSchema = MISSING
    scenario: ScenarioSchema = MISSING
    method: Any = MISSING            # checked against METHODS[method.name]
    recorder: RecorderSchema = field(default_factory=RecorderSchema)
    sim: SimConfig = field(default_factory=SimConfig)
    disturbance: Disturbance = field(default_factory=Disturbance)
    seed: int = 0
    output_root: str = "runs"        # every run writes into a new folder below this
    stop_on_success: bool = True     # end the episode once the hand rests in the goal ball
    settle_time: float = 2.0         # [s] the run goes on at least this long after the reach
    rest_window: float = 1.0         # [s] at rest: the hand moved less than rest_distance
    rest_distance: float = 0.005     # [m] relative to the goal over the last rest_window
    rest_angle: float = 0.02         # [rad] ... and the hand turned less than this (its pose)
    without_obstacles: bool = False  # drop the scenario's obstacles (path-difference runs)
    clutter: ClutterSchema = field(default_factory=ClutterSchema)
    suite: SuiteSchema = field(default_factory=SuiteSchema)  # the frozen suite of the run

    def __post_init__(self):
        _check(self.seed >= 0, "seed", "an integer >= 0", self.seed)
        _nonneg("settle_time", self.settle_time)
        _positive("rest_window", self.rest_window)
        _positive("rest_distance", self.rest_distance)
        _positive("rest_angle", self.rest_angle)
        sim = self.sim
        _check(sim.control != "impedance" or self.robot.impedance is not None, "sim.control",
               f"velocity for robot {self.robot.name}: its config has no impedance gains "
               "(robot.impedance)", sim.control)
        _check(_finite(sim.substep) and 0 < sim.substep <= 0.1, "sim.substep", "in (0, 0.1] s",
               sim.substep)
        _check(_finite(sim.gravity), "sim.gravity", "finite", sim.gravity)
        _positive("sim.max_joint_force", sim.max_joint_force)
        ratio = self.scenario.dt / sim.substep
        _check(round(ratio) >= 1, "scenario.dt", f"at least sim.substep = {sim.substep:g} s "
               "(one physics step per control period)", self.scenario.dt)
        _check(abs(ratio - round(ratio)) <= 1e-6 * max(1.0, ratio), "scenario.dt",
               f"a multiple of sim.substep = {sim.substep:g} s", self.scenario.dt)
        _check(round(ratio) <= MAX_SUBSTEPS_PER_STEP, "scenario.dt / sim.substep",
               f"at most {MAX_SUBSTEPS_PER_STEP} physics substeps per control period",
               round(ratio))


@dataclass
class PumaSchema:
    """The PUMA primitive and its training (``conf/puma/*.yaml``)."""

    orientation: bool = True         # R3 x S3 (false: position only)
    order: int = 2                   # 2: acceleration model; 1: velocity model
    dt: float = 0.03                 # model step [s]
    smoothing: float = 0.0           # Gaussian smoothing of the demonstrations [samples]
    hold: int = 10                   # rest samples appended on the goal per demonstration
    network: NetConfig = field(default_factory=NetConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def __post_init__(self):
        _check(self.order in (1, 2), "puma.order", "1 or 2", self.order)
        _check(_finite(self.dt) and 0 < self.dt <= 1.0, "puma.dt", "in (0, 1] s", self.dt)
        _nonneg("puma.smoothing", self.smoothing)
        _check(0 <= self.hold <= 10_000, "puma.hold", "in [0, 10000]", self.hold)


@dataclass
class TrainRunConfig:
    """One training (``conf/train.yaml``): ``python -m tamedpuma.train``."""

    task: TaskSchema = MISSING
    puma: PumaSchema = field(default_factory=PumaSchema)
    seed: int = 0
    out_dir: str = MISSING           # checkpoint puma.pt and report.json go here
    overwrite: bool = False          # replace an existing checkpoint in out_dir
    save_every: int = 100            # save the resumable state every N iterations (0: never)
    evaluate: bool = True            # evaluate after training (stored in the checkpoint)
    progress: bool = True            # progress bar with the losses
    bench_out: str | None = None  # if set, also write a benchmark summary JSON there

    def __post_init__(self):
        _check(self.seed >= 0, "seed", "an integer >= 0", self.seed)
        _check(self.save_every >= 0, "save_every", "an integer >= 0", self.save_every)


@dataclass
class BodyModelRunConfig:
    """Fitting a robot's collision spheres (``conf/body_model.yaml``):
    ``python -m tamedpuma.body_model``."""

    robot: RobotSchema = MISSING
    tolerance: float = 0.0           # [m] a collision-mesh vertex may lie this far outside
    max_spheres: int = 3             # per link
    k_penalty: float = 0.15          # relative cost of one more sphere when choosing how many
    samples: int = 100_000           # Monte-Carlo samples per link for the volumes
    out: str | None = None           # null: into the robot's own config file, between markers

    def __post_init__(self):
        _nonneg("tolerance", self.tolerance)
        _check(1 <= self.max_spheres <= 100, "max_spheres", "in [1, 100]", self.max_spheres)
        _nonneg("k_penalty", self.k_penalty)
        _check(1 <= self.samples <= 10_000_000, "samples", "in [1, 10000000]", self.samples)


# ----------------------------------------------------------------------------- merging


def _writable(node) -> None:
    """Structured nodes of frozen dataclasses are read-only: let YAML values merge into them."""
    OmegaConf.set_readonly(node, False)
    if node._is_missing() or node._is_none():  # a required list or node: nothing inside yet
        return
    if isinstance(node, DictConfig):
        for key in node.keys():
            child = node._get_node(key)
            if isinstance(child, (DictConfig, ListConfig)):
                _writable(child)
    elif isinstance(node, ListConfig):
        for child in node._iter_ex(resolve=False):
            if isinstance(child, (DictConfig, ListConfig)):
                _writable(child)


_SCHEMA_NODES: dict[type, DictConfig] = {}  # schema -> its writable structured node


def _schema_node(schema: type) -> DictConfig:
    """``schema``'s structured node, writable (:func:`_writable`), built once per process: a
    run's typing merges into a deep copy of it (``OmegaConf.merge``), never into the node
    itself, so every run starts from the same defaults (building it costs a quarter of the
    typing, once per job of a sweep without this)."""
    if schema not in _SCHEMA_NODES:
        node = OmegaConf.structured(schema)
        _writable(node)
        _SCHEMA_NODES[schema] = node
    return _SCHEMA_NODES[schema]


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).splitlines()[0].split())


def typed(schema: type, cfg, where: str = ""):
    """``cfg`` (a mapping or DictConfig) merged into ``schema`` and built: an instance of
    ``schema``. A wrong type, unknown key, missing value or out-of-range value raises
    :class:`ConfigError` naming the key (prefixed by ``where``)."""
    try:
        merged = OmegaConf.merge(_schema_node(schema), cfg)  # merges into a deep copy
        return OmegaConf.to_object(merged)
    except ConfigError:
        raise
    except OmegaConfBaseException as exc:
        cause = exc.__cause__ or exc.__context__
        if isinstance(cause, ConfigError):
            raise cause from None
        if isinstance(cause, (ValueError, TypeError)) and not isinstance(
                cause, OmegaConfBaseException):  # a library dataclass's own check
            raise ConfigError(" ".join(str(cause).split())) from None
        key = getattr(exc, "full_key", None) or ""
        prefix = ".".join(k for k in (where, key) if k)
        text = _one_line(exc)
        if "not in" in text and key:
            text = f"unknown key (misspelt?): {text}"
        raise ConfigError(f"{prefix}: {text}" if prefix else text) from None
    except (TypeError, ValueError) as exc:  # a library dataclass's own check
        raise ConfigError(f"{where}: {_one_line(exc)}" if where else _one_line(exc)) from None


def method_options(cfg) -> MethodSchema:
    """A method config checked against its method's dataclass (:data:`METHODS`)."""
    if "name" not in cfg:
        raise ConfigError("method.name is not set")
    name = str(cfg["name"])
    if name not in METHODS:
        raise ConfigError(f"unknown method {name!r}; choose one of {sorted(METHODS)}")
    if isinstance(cfg, dict):  # plain values (run_config's): typed once per process
        return _typed_once(METHODS[name], cfg, "method")
    return typed(METHODS[name], cfg, "method")


def method_settings(method) -> Any:
    """The frozen settings a method's ``make`` takes
    (:func:`tamedpuma.methods.settings_type`), from a typed method config (``RunConfig.method``)
    or a method config mapping (typed first by :func:`method_options`)."""
    from tamedpuma.methods import settings_type

    if not isinstance(method, MethodSchema):
        method = method_options(method)
    library = settings_type(method.name)
    return library(**{f.name: getattr(method, f.name) for f in dataclasses.fields(library)})


#: typed sections by (schema, where, the section's canonical JSON), per process, at most
#: :data:`TYPED_KEPT`: the jobs of a sweep repeat them (Table 1: 8 methods × 60 scenario
#: settings; the randomized suite: 8 methods × 800), and typing a whole run config costs ~75 ms
_TYPED: dict[tuple, Any] = {}
TYPED_KEPT = 256


def _typed_once(schema: type, plain: dict, where: str = ""):
    """:func:`typed` of the plain (resolved) mapping, computed once per process for equal
    input; each call gets its own deep copy (a caller may set its fields). Errors are raised
    every time (nothing is kept for them)."""
    try:
        key = (schema, where, json.dumps(plain, sort_keys=True, default=repr))
    except (TypeError, ValueError):  # keys JSON cannot sort (mixed types): typed afresh
        return typed(schema, plain, where)
    if key not in _TYPED:
        if len(_TYPED) >= TYPED_KEPT:
            _TYPED.pop(next(iter(_TYPED)))
        _TYPED[key] = typed(schema, plain, where)
    return copy.deepcopy(_TYPED[key])


#: schema -> (its dataclass-typed fields by name, a dataclass of its other fields), per process
_SPLIT: dict[type, tuple[dict[str, type], type]] = {}


def _split_schema(schema: type) -> tuple[dict[str, type], type]:
    """``schema``'s sections (its fields whose type is a dataclass, by name) and a dataclass of
    the same name holding its other fields (the same names, types and defaults)."""
    if schema not in _SPLIT:
        hints = typing.get_type_hints(schema)
        fields = dataclasses.fields(schema)
        sections = {f.name: hints[f.name] for f in fields
                    if dataclasses.is_dataclass(hints[f.name])}
        rest = [(f.name, hints[f.name],
                 field(default=f.default) if f.default is not dataclasses.MISSING
                 else field(default_factory=f.default_factory))
                for f in fields if f.name not in sections]
        _SPLIT[schema] = (sections, dataclasses.make_dataclass(schema.__name__, rest))
    return _SPLIT[schema]


def _typed_by_section(schema: type, plain: dict):
    """:func:`typed` of ``plain`` as ``schema``, each section typed on its own and once per
    process for equal values (:func:`_typed_once`), then ``schema``'s own checks: the jobs of a
    sweep share most sections (Table 1: the robot, simulator and recorder sections in all 480
    jobs, each scenario's in 16), so a job types little of its config afresh (about a third of
    the time of typing it whole). The same object as :func:`typed`
    (``tests/test_schema.py``); any error is :func:`typed`'s own, raised by typing the whole
    mapping."""
    sections, values = _split_schema(schema)
    try:
        if any(name not in plain and schema.__dataclass_fields__[name].default is MISSING
               for name in sections):
            raise LookupError("a required section is missing")
        parts = {name: _typed_once(tp, plain[name], name)
                 for name, tp in sections.items() if name in plain}
        rest = _typed_once(values, {k: v for k, v in plain.items() if k not in sections})
        return schema(**parts, **{f.name: getattr(rest, f.name)
                                  for f in dataclasses.fields(values)})
    except Exception:  # noqa: BLE001 - typing the whole mapping raises the error to report
        return typed(schema, plain)


def run_config(cfg) -> RunConfig:
    """The whole run config (resolved), typed and range-checked (each section typed once per
    process for equal values, :func:`_typed_by_section`)."""
    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    plain = OmegaConf.to_container(cfg, resolve=True)
    method = method_options(plain.get("method") or {})
    run = _typed_by_section(RunConfig, {**plain, "method": {}})
    run.method = method
    return run


def train_config(cfg) -> TrainRunConfig:
    """The whole training config (resolved), typed and range-checked."""
    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    plain = OmegaConf.to_container(cfg, resolve=True)
    plain.pop("command", None)
    return typed(TrainRunConfig, plain)


def body_model_config(cfg) -> BodyModelRunConfig:
    """The ``python -m tamedpuma.body_model`` config (resolved), typed and range-checked."""
    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    return typed(BodyModelRunConfig, OmegaConf.to_container(cfg, resolve=True))


#: top-level config name -> its typing function (the entry points' ``compose``)
CONFIGS = {"sweep": run_config, "train": train_config, "body_model": body_model_config}


def as_dict(obj) -> dict:
    """A typed config object as a plain dict (tuples as lists), e.g. for a method's ``make``."""
    def plain(v):
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v
    return plain(dataclasses.asdict(obj))


def _node(schema: type):
    node = OmegaConf.structured(schema)
    _writable(node)
    return node


def register() -> None:
    """Register the schemas in Hydra's ConfigStore: ``tamedpuma_sweep``, ``tamedpuma_train`` and
    ``tamedpuma_body_model`` head the defaults lists of ``conf/sweep.yaml``, ``conf/train.yaml``
    and ``conf/body_model.yaml`` (so every schema key exists in the composed config with its
    default, and the YAML overrides it), ``tamedpuma_method/<name>`` are the method option
    groups."""
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    store.store(name="tamedpuma_sweep", node=_node(RunConfig))
    store.store(name="tamedpuma_train", node=_node(TrainRunConfig))
    store.store(name="tamedpuma_body_model", node=_node(BodyModelRunConfig))
    for name, schema in METHODS.items():
        store.store(group="tamedpuma_method", name=name, node=_node(schema))


register()

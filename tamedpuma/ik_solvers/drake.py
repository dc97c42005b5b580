"""Drake backend: ``InverseKinematics`` with ``AddMinimumDistanceLowerBoundConstraint`` (SNOPT).

The robot is Drake's ``MultibodyPlant`` parsed from the same URDF (meshes stripped: the collision
model is ours), with the robot's body spheres registered as collision geometry on their links.
Each obstacle is a sphere on a body welded to a ``FixedOffsetFrame`` of the world; the frame's pose
is a context parameter, so moving obstacles are updated per solve without rebuilding anything and
without adding decision variables (7 positions only). Robot-robot and obstacle-obstacle pairs are
filtered, so the minimum-distance constraint is exactly ``min_ij d_ij(q) ≥ d_min`` over the
(body sphere, obstacle) pairs. One plant is built per (robot, obstacle radii) and cached.

Drake's minimum-distance constraint is a smoothed penalty that is feasible iff every pair is beyond
its bound; the bound passed to Drake is ``d_min + options.drake_margin`` (1e-4 m by default:
:class:`~tamedpuma.ik_solvers.problem.SolverOptions`) so that SNOPT's feasibility tolerance cannot
leave a pair below d_min. The objective is scaled by ``1/s²`` (s = ``options.scale``, 0.01 m), as
in the SLSQP backend; the minimiser is the same. Unscaled, a step of a fraction of a millimetre
(Modulation-IK's slow final approach, 9 mm/s × 0.02 s) improves the objective by ~10⁻⁸, below
SNOPT's optimality tolerance: SNOPT returned the start and the arm stood 5.6 cm from the goal
for 30 s (Table-1 pouring 0). SNOPT reports no iteration count through Drake:
``iterations`` is the number of objective evaluations (counted by a visualization callback).

The program is built once per world and reused by every solve (:class:`_Program`): the trust box
takes each problem's bounds, the minimum-distance constraint is replaced only when its bound or
influence distance changes, and the costs are replaced in the order a fresh program adds them, so
SNOPT sees the same program as from a fresh build (the same iterates to the bit) without Drake
creating the decision variables, the program and SNOPT's options at every step. SNOPT's
``Major print level`` is 0: at its default (1) SNOPT formats a log line per major iteration and
its exit report (Fortran internal writes, ~0.3 ms of a ~1.5 ms solve) even with no print file to
write them to; the print level changes no iterate.
"""

from __future__ import annotations

import importlib.util
import re
import time
from dataclasses import dataclass, field

import numpy as np

from tamedpuma.errors import ConfigError

from .problem import IKProblem, IKResult, robot_key

_PYDRAKE: list = []  # the imported pydrake.all, once (an optional, heavy dependency: ~1 s)


def available() -> bool:
    """Whether Drake is installed (without importing it)."""
    return importlib.util.find_spec("pydrake") is not None


def _pydrake():
    if not _PYDRAKE:
        if not available():
            raise ConfigError("ik backend 'drake' needs Drake: pip install drake "
                              "(or choose the slsqp backend)")
        import pydrake.all

        _PYDRAKE.append(pydrake.all)
    return _PYDRAKE[0]


@dataclass
class _Program:
    """The IK program of one world, reused by every solve (module docstring): Drake's
    InverseKinematics ``ik`` and its program ``prog``, the decision variables ``q`` (the plant's
    positions, in the program's order) and ``qv`` (the robot's joints), the trust-box constraint
    ``box``, the minimum-distance constraint ``distance`` with its (bound, influence) [m], the
    costs of the last solve, the evaluation counter, SNOPT and its options (for
    ``max_iterations``)."""

    ik: object
    prog: object
    q: np.ndarray
    qv: np.ndarray
    box: object
    counter: list
    solver: object
    options: object
    max_iterations: int = -1
    distance: object = None
    distance_key: tuple | None = None
    costs: list = field(default_factory=list)


@dataclass
class _World:
    diagram: object
    context: object
    plant: object
    plant_context: object
    position_index: np.ndarray
    ee_frame: object
    obstacle_frames: list
    program: _Program | None = None


_WORLDS: dict = {}


def _kinematics_only(urdf_text: str) -> str:
    """The URDF without its visual, collision and inertial elements: the IK's plant needs the
    kinematic tree alone (its collision geometry is the body spheres), and Drake warns on a
    link whose inertia has no mass (the iiwa's base, welded to the world here)."""
    for tag in ("visual", "collision", "inertial"):
        urdf_text = re.sub(rf"<{tag}>.*?</{tag}>", "", urdf_text, flags=re.S)
    return urdf_text


def _build(kinematics, radii: tuple[float, ...]) -> _World:
    pd = _pydrake()
    spec = kinematics.spec
    builder = pd.DiagramBuilder()
    plant, scene_graph = pd.AddMultibodyPlantSceneGraph(builder, 0.0)
    with open(spec.urdf_path) as f:
        robot = pd.Parser(plant).AddModelsFromString(_kinematics_only(f.read()), "urdf")[0]
    base = plant.GetFrameByName(spec.link_names[0], robot)
    plant.WeldFrames(plant.world_frame(), base)
    friction = pd.CoulombFriction()
    robot_geoms = [
        plant.RegisterCollisionGeometry(plant.GetBodyByName(s.link, robot),
                                        pd.RigidTransform(np.array(s.offset)), pd.Sphere(s.radius),
                                        f"body_sphere_{i}", friction)
        for i, s in enumerate(spec.spheres)]
    obstacle_frames, obstacle_geoms = [], []
    for j, r in enumerate(radii):
        instance = plant.AddModelInstance(f"obstacle_{j}")
        body = plant.AddRigidBody(f"obstacle_{j}", instance,
                                  pd.SpatialInertia.SolidSphereWithMass(1.0, r))
        frame = plant.AddFrame(pd.FixedOffsetFrame(f"obstacle_frame_{j}", plant.world_frame(),
                                                   pd.RigidTransform()))
        plant.WeldFrames(frame, body.body_frame())
        obstacle_geoms.append(plant.RegisterCollisionGeometry(
            body, pd.RigidTransform(), pd.Sphere(r), f"obstacle_{j}", friction))
        obstacle_frames.append(frame)
    plant.Finalize()
    manager = scene_graph.collision_filter_manager()
    manager.Apply(pd.CollisionFilterDeclaration().ExcludeWithin(pd.GeometrySet(robot_geoms)))
    if len(obstacle_geoms) > 1:
        manager.Apply(pd.CollisionFilterDeclaration().ExcludeWithin(
            pd.GeometrySet(obstacle_geoms)))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    index = np.array([plant.GetJointByName(n, robot).position_start() for n in spec.joint_names])
    if plant.num_positions() != spec.dof:
        raise ConfigError(f"drake plant has {plant.num_positions()} positions, expected {spec.dof}")
    return _World(diagram, context, plant, plant_context, index,
                  plant.GetFrameByName(spec.ee_link, robot), obstacle_frames)


def _world(kinematics, radii: np.ndarray) -> _World:
    key = (robot_key(kinematics), tuple(float(r) for r in radii))
    if key not in _WORLDS:
        if len(_WORLDS) >= 8:
            _WORLDS.pop(next(iter(_WORLDS)))
        _WORLDS[key] = _build(kinematics, key[1])
    return _WORLDS[key]


def warm_up(kinematics, radii: np.ndarray) -> None:
    """Import Drake and build (cache) the plant for these obstacle radii, outside the timed loop."""
    _world(kinematics, np.asarray(radii, float))


def _program(world: _World, max_iterations: int) -> _Program:
    """The world's program (built at its first solve) with SNOPT's options for
    ``max_iterations``."""
    pd = _pydrake()
    program = world.program
    if program is None:
        ik = pd.InverseKinematics(world.plant, world.plant_context, with_joint_limits=False)
        prog = ik.get_mutable_prog()
        q = ik.q()
        if list(prog.FindDecisionVariableIndices(q)) != list(range(len(q))):
            raise ConfigError("drake's IK program holds variables other than the positions")
        qv = q[world.position_index]
        box = prog.AddBoundingBoxConstraint(np.full(len(qv), -np.inf), np.full(len(qv), np.inf),
                                            qv)
        counter = [0]

        def _count(_x):  # called with the iterate (floats) at every evaluation of the program
            counter[0] += 1

        # A visualization callback, not a zero cost: Drake calls it once per evaluation as it
        # did the cost (the same count), but with floats, where a Python cost is called with
        # AutoDiff arrays for its gradient (~10 µs per evaluation, ~0.2 ms of a 1.2 ms solve)
        prog.AddVisualizationCallback(_count, qv[:1])
        program = world.program = _Program(ik, prog, q, qv, box, counter, pd.SnoptSolver(),
                                           pd.SolverOptions())
        program.options.SetOption(program.solver.id(), "Major print level", 0)
    if program.max_iterations != max_iterations:
        program.options.SetOption(program.solver.id(), "Major iterations limit", max_iterations)
        program.max_iterations = max_iterations
    return program


def _set_constraints(program: _Program, problem: IKProblem) -> None:
    """The trust box ``q_lower ≤ q ≤ q_upper`` and, with obstacles, Drake's minimum distance
    ``≥ d_min + drake_margin`` [m] (module docstring), replaced only when it changes."""
    program.box.evaluator().set_bounds(problem.q_lower, problem.q_upper)
    key = None
    if problem.n_obstacles:
        key = (problem.d_min + float(problem.options.drake_margin),
               float(problem.options.drake_influence))
    if key == program.distance_key:
        return
    if program.distance is not None:
        program.prog.RemoveConstraint(program.distance)
        program.distance = None
    if key is not None:
        program.distance = program.ik.AddMinimumDistanceLowerBoundConstraint(*key)
    program.distance_key = key


def _set_costs(program: _Program, world: _World, problem: IKProblem) -> None:
    """The objective ×1/s² (module docstring): the position, orientation and regularisation
    costs, replacing the last solve's, added in the order of a fresh program."""
    pd = _pydrake()
    ik, prog = program.ik, program.prog
    for binding in program.costs:
        prog.RemoveCost(binding)
    scale = 1.0 / float(problem.options.scale) ** 2  # the objective ×1/s², as SLSQP's
    world_frame = world.plant.world_frame()
    costs = [ik.AddPositionCost(world_frame, problem.target_position, world.ee_frame,
                                np.zeros(3), scale * problem.position_weight * np.eye(3))]
    if problem.target_rotation is not None and problem.orientation_weight > 0:
        costs.append(ik.AddOrientationCost(world_frame, pd.RotationMatrix(problem.target_rotation),
                                           world.ee_frame, pd.RotationMatrix(),
                                           scale * problem.orientation_weight))
    costs.append(prog.AddQuadraticErrorCost(
        scale * problem.regularization_weight * np.eye(len(program.qv)), problem.q_ref,
        program.qv))
    program.costs = costs


def solve(problem: IKProblem) -> IKResult:
    """Solve ``problem`` with Drake's InverseKinematics and SNOPT (module docstring)."""
    pd = _pydrake()
    start = time.perf_counter()
    world = _world(problem.kinematics, problem.obstacle_radii)
    plant, pctx, idx = world.plant, world.plant_context, world.position_index
    for frame, center in zip(world.obstacle_frames, problem.obstacle_centers):
        frame.SetPoseInParentFrame(pctx, pd.RigidTransform(center))
    q_full = np.zeros(plant.num_positions())
    q_full[idx] = np.clip(problem.q_start, problem.q_lower, problem.q_upper)
    plant.SetPositions(pctx, q_full)

    program = _program(world, int(problem.max_iterations))
    _set_constraints(program, problem)
    _set_costs(program, world, problem)
    program.counter[0] = 0
    result = program.solver.Solve(program.prog, q_full, program.options)
    q = result.get_x_val()[idx]  # the decision variables are the plant's positions, in order
    info = result.get_solver_details().info
    elapsed = (time.perf_counter() - start) * 1e3
    return IKResult(q=np.asarray(q, float), success=bool(result.is_success()),
                    message=f"SNOPT info {info}: {result.get_solution_result().name}",
                    iterations=program.counter[0], max_violation=float("nan"),
                    min_distance=float("nan"), backend="drake", solve_time_ms=elapsed)

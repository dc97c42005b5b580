"""Our vanilla fabric (``method=fabrics``) against the reference planner, the GPL ``fabrics``
package 0.10.0 (Spahn et al.), on seeded random states of our iiwa: q uniform inside the joint
limits, two obstacle spheres near the arm, a goal; at q̇ = 0 and at random q̇.

The reference runs in its own venv (``tamedpuma/app/reference_actions.py`` under the interpreter
named by ``TAMEDPUMA_REFERENCE_PYTHON``; ``.ci/run`` makes one); without it these tests skip.
Both planners are built the same way: base metric 0.2 I; every body sphere against every
obstacle (energy 0.1 ẋ²/x, geometry ẍ = 0.5 s(ẋ) ẋ²/x⁵); both limits of every joint (energy
0.1 s(ẋ) ẋ²/x, geometry ẍ = 0.1 ẋ²/x); the goal attractor on the end effector's position
(potential gradient 5 tanh(10‖e‖) e/‖e‖, metric 2((2 − 0.3) exp(−(0.75‖e‖)²) + 0.3) I); the
reference's speed control (η = ½(tanh(−0.45‖q̇‖² − 0.5) + 1),
β = 3.25(tanh(−0.5(‖e‖ − 0.02)) + 1) + 0.01 + max(0, α_G − α_ex)).

Our settings for the comparison, where our defaults differ from the reference on purpose:

- ``conf/fabric/reference.yaml``: the reference's joint-limit leaf (ours: exponents 2, gains
  0.05) and ``obstacle_activation: .inf`` (ours tapers the obstacle energy to 0 at x = 2);
- ``orientation_weight: 0``: the reference's goal is the position alone (ours also attracts two
  axes of the hand);
- the robot's five body spheres (``robot.spheres``, link origins), without ``guard_spheres``;
- no ground leaf (``ground_enabled: false``, as in reference.yaml);
- at q̇ = 0 only: the joint-limit energy non-directional with half its gain. The reference's
  s(ẋ) = ½(1 − sign ẋ) is ½ at ẋ = 0, so at rest its directional limit energy keeps half its
  metric 0.1/x; ours takes s(0) = 0 (a joint at rest does not approach its limit). At q̇ = 0 every
  other term of that leaf carries ẋ², so the half-gain non-directional energy is exactly the
  reference's there (the test checks it matters: without it the actions differ).

What differs beyond these settings, each checked exactly, never by a looser tolerance:

- the reference solves ``(M + 10⁻⁶ I) q̈ = −f`` (pseudo-inverse): at q̇ = 0 its action and ours
  differ by at most 10⁻⁶/λ_min(M + M_ψ) relatively (≤ 5·10⁻⁶, as M ⪰ 0.2 I), and by rounding once
  ours is solved with the same 10⁻⁶ I;
- its execution-energy coefficients are q̇ᵀq̈/(‖q̇‖² + ε/2) (metric 2I, ε added once), ours use ε;
- at q̇ ≠ 0 its known sign error (method.md §2): every pullback of a geometry force uses −J̇q̇,
  ``f = Jᵀ(M_L h − M_L J̇q̇)`` for each leaf and ``Jᵀ g (∇ψ − J̇q̇)`` for the attractor, where ours
  (and the textbook) use +J̇q̇. Its energies are pulled by substituting the map into L, which is
  exact, so f_L (energization) has the right sign in both. The test rebuilds our action from
  our own library's terms (checked to reproduce ``method=fabrics`` to rounding) with exactly that
  term's sign flipped, and finds the reference's action to rounding; with our sign the two
  differ by far more than the tolerance.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import tamedpuma.app
from tamedpuma.app.config import load_group
from tamedpuma.app.schema import method_settings
from tamedpuma.fabrics.speed import speed_terms
from tamedpuma.methods import fabrics
from tamedpuma.types import Observation


def make(cfg, kinematics):
    """The Fabrics controller of a plain method config (Hydra's ``defaults`` list left out),
    typed by the schema."""
    return fabrics.make(method_settings({k: v for k, v in cfg.items() if k != "defaults"}),
                        kinematics)


SCRIPT = Path(tamedpuma.app.__file__).resolve().parent / "reference_actions.py"
ENV = "TAMEDPUMA_REFERENCE_PYTHON"
EPS = 1e-6  # the reference's regularisation (fabrics.helpers.constants.eps)
ROUNDING = 1e-10  # relative: what double-precision linear algebra on these 7×7 systems leaves
N_CASES = 16  # per kind (at rest, moving)
N_OBSTACLES = 2
SEED = 20260401


def _config(at_rest: bool) -> dict:
    """The method config of ``method=fabrics`` set up as the reference (the module doc lists
    each setting)."""
    fabric = load_group("fabric", "reference")
    fabric.update(orientation_weight=0.0, ground_enabled=False, kernel="numpy")
    if at_rest:  # the reference's s(0) = ½ on the directional limit energy
        fabric["joint_limit"] = dict(fabric["joint_limit"], energy_directional=False,
                                     energy_gain=0.5 * fabric["joint_limit"]["energy_gain"])
    return {"name": "fabrics", "fabric": fabric}


def _obstacles(rng, centers, radii):
    """Two obstacle spheres, each 2-25 cm from a random body sphere and ≥ 2 cm from all."""
    out_c, out_r = [], []
    while len(out_c) < N_OBSTACLES:
        i = rng.integers(len(radii))
        r = rng.uniform(0.05, 0.15)
        u = rng.normal(size=3)
        c = centers[i] + u / np.linalg.norm(u) * (radii[i] + r + rng.uniform(0.02, 0.25))
        if np.min(np.linalg.norm(centers - c, axis=1) - radii - r) >= 0.02:
            out_c.append(c)
            out_r.append(r)
    return np.array(out_c), np.array(out_r)


def _cases(spec, kinematics) -> list[dict]:
    """Seeded random cases: q inside the limits (2 cm away), q̇ = 0 for the first N_CASES and
    N(0, 0.5 rad/s) per joint after, two obstacles near the arm, a goal in front of the robot."""
    rng = np.random.default_rng(SEED)
    cases = []
    for k in range(2 * N_CASES):
        q = rng.uniform(spec.q_min + 0.02, spec.q_max - 0.02)
        qd = np.zeros(spec.dof) if k < N_CASES else rng.normal(0.0, 0.5, spec.dof)
        centers, radii = _obstacles(rng, kinematics.sphere_centers(q), spec.sphere_radii)
        goal = rng.uniform([0.3, -0.5, 0.1], [0.7, 0.5, 0.8])
        cases.append({"q": q, "qd": qd, "goal_position": goal, "centers": centers,
                      "radii": radii})
    return cases


def _payload(spec, cases) -> dict:
    return {"urdf_path": str(spec.urdf_path), "root_link": spec.link_names[0],
            "ee_link": spec.ee_link, "q_min": spec.q_min.tolist(), "q_max": spec.q_max.tolist(),
            "spheres": [{"link": s.link, "radius": s.radius} for s in spec.spheres],
            "goal_weight": 1.0, "n_obstacles": N_OBSTACLES,
            "cases": [{k: np.asarray(v).tolist() for k, v in c.items()} for c in cases]}


def _run_script(python, path: Path, timeout: float = 900.0):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    return subprocess.run([str(python), str(SCRIPT), "--input", str(path)], env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def reference_python():
    python = os.environ.get(ENV)
    if not python:
        pytest.skip(f"{ENV} is not set: no venv with the reference `fabrics` 0.10.0 package "
                    "(.ci/run makes one)")
    return python


@pytest.fixture(scope="module")
def compared(reference_python, robot_spec, kinematics, tmp_path_factory):
    """(cases, the reference's results) for the seeded cases."""
    cases = _cases(robot_spec, kinematics)
    path = tmp_path_factory.mktemp("reference") / "cases.json"
    path.write_text(json.dumps(_payload(robot_spec, cases)))
    proc = _run_script(reference_python, path)
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines() or ["no output"]
        pytest.fail(f"reference_actions.py under {reference_python} exited with "
                    f"{proc.returncode}: {lines[-1]}")
    out = json.loads(proc.stdout)
    assert out["fabrics_version"] == "0.10.0"
    return cases, out["cases"]


def _ours(kinematics, case, at_rest: bool, cfg=None):
    """Our action (``method=fabrics``'s controller, configured as the reference) and its
    controller."""
    controller = make(cfg or _config(at_rest), kinematics)
    centers = np.asarray(case["centers"])
    obs = Observation(t=0.0, step=0, q=case["q"], qd=case["qd"], obstacle_centers=centers,
                      obstacle_radii=np.asarray(case["radii"]),
                      obstacle_velocities=np.zeros_like(centers),
                      goal_position=case["goal_position"],
                      goal_quaternion=np.array([0.0, 0.0, 0.0, 1.0]), goal_velocity=np.zeros(3))
    command = controller.step(obs)
    assert command.scalars["n_clamped"] == 0 and command.scalars["n_limit_clamped"] == 0
    return command.qdd, controller


def _rebuilt(controller, kinematics, case, curvature_sign: float, reg: float, eps_ex: float):
    """Our action rebuilt from our library's terms (the same maths as ``Fabric.evaluate``) with
    the sign of the curvature term J̇q̇ in the geometry pullbacks, the solves' regularisation
    ``reg I`` and the execution-energy ε as given: (+1, 0, ε) is ours, (−1, 10⁻⁶, ε/2) the
    reference's (module doc)."""
    fabric, gains = controller.fabric, controller.gains
    q, qd = case["q"], case["qd"]
    state = kinematics.evaluate(q, qd)
    centers = np.asarray(case["centers"])
    av = fabric.avoidance(state, q, qd, centers, np.asarray(case["radii"]),
                          np.zeros_like(centers))
    A, m, jd = av.barrier_rows, av.barrier_metric, av.barrier_jdqd
    # the rows carry the whole metric: M = m_b I + Σ_r m_r a_r a_rᵀ (so Σ_r a_r m_r J̇q̇_r is the
    # whole curvature force of the barrier leaves; the base leaf has none)
    np.testing.assert_allclose(av.M, gains.base_metric * np.eye(len(q)) + A.T @ (m[:, None] * A),
                               rtol=1e-12, atol=1e-12)
    f = av.f + (curvature_sign - 1.0) * (A.T @ (m * jd))
    # the attractor's curvature is the end effector's J̇q̇ (position rows; orientation is off)
    flipped = dataclasses.replace(state, ee_jdqd=curvature_sign * state.ee_jdqd)
    forcing = fabric.forcing(flipped, qd, case["goal_position"], np.eye(3))
    eye = reg * np.eye(len(q))
    qdd_g = -np.linalg.solve(av.M + eye, f)
    qdd_f = -np.linalg.solve(av.M + forcing.M + eye, f + forcing.f)
    alpha_g = qd @ (av.f_energy - f) / (qd @ av.M @ qd + gains.energization_eps)
    terms = speed_terms(float(qd @ qd), float(qd @ qdd_g), float(qd @ qdd_f), alpha_g,
                        forcing.goal_distance,
                        dataclasses.replace(gains, energization_eps=eps_ex))
    return qdd_f - (terms.alpha_ex + terms.beta) * qd


def _relative(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a) - b) / np.linalg.norm(b))


def test_same_robot_and_body_spheres(compared, kinematics):
    cases, results = compared
    for case, res in zip(cases, results):
        state = kinematics.evaluate(case["q"], case["qd"])
        np.testing.assert_allclose(res["ee_position"], state.ee_position, atol=1e-9)
        np.testing.assert_allclose(res["sphere_centers"], state.sphere_centers, atol=1e-9)


def test_reference_actions_are_not_zeroed(compared):
    """compute_action returns 0 for ‖q̈‖ < 10⁻⁶ or > 10⁶: no case may hit either."""
    for res in compared[1]:
        assert 1e-6 < np.linalg.norm(res["action"]) < 1e6


def test_at_rest_our_action_is_the_references(compared, kinematics):
    cases, results = compared
    for case, res in list(zip(cases, results))[:N_CASES]:
        assert not np.any(case["qd"])
        ref = np.asarray(res["action"])
        ours, controller = _ours(kinematics, case, at_rest=True)
        # the reference solves (M_F + 10⁻⁶ I) q̈ = −f_F, M_F = M + M_ψ: ours − ref = 10⁻⁶ M_F⁻¹ ref
        fabric, state = controller.fabric, kinematics.evaluate(case["q"], case["qd"])
        av = fabric.avoidance(state, case["q"], case["qd"], case["centers"], case["radii"],
                              np.zeros((N_OBSTACLES, 3)))
        m_f = av.M + fabric.forcing(state, case["qd"], case["goal_position"], np.eye(3)).M
        assert _relative(ours, ref) <= EPS / np.linalg.eigvalsh(m_f)[0] + ROUNDING
        # with the same regularisation: to rounding
        assert _relative(_rebuilt(controller, kinematics, case, 1.0, EPS, EPS), ref) < ROUNDING
        # ...and the rebuild is our action
        assert _relative(_rebuilt(controller, kinematics, case, 1.0, 0.0,
                                  controller.gains.energization_eps), ours) < ROUNDING


def test_at_rest_the_limit_metric_matters(compared, kinematics):
    """Without the reference's s(0) = ½ on the limit energy the actions differ well beyond the
    tolerance: the comparison sees the joint-limit leaf."""
    cases, results = compared
    least = min(_relative(_ours(kinematics, case, at_rest=False)[0], res["action"])
                for case, res in list(zip(cases, results))[:N_CASES])
    assert least > 100 * EPS / 0.2  # in every case, beyond 100× the regularisation's bound


def test_moving_our_action_is_the_references_up_to_its_curvature_sign(compared, kinematics):
    cases, results = compared
    differences = []
    for case, res in list(zip(cases, results))[N_CASES:]:
        assert np.linalg.norm(case["qd"]) > 0.1
        ref = np.asarray(res["action"])
        ours, controller = _ours(kinematics, case, at_rest=False)
        eps = controller.gains.energization_eps
        # the rebuild with our sign is our method's action, to rounding
        assert _relative(_rebuilt(controller, kinematics, case, 1.0, 0.0, eps), ours) < ROUNDING
        # the rebuild with the reference's −J̇q̇ (and its ε's) is the reference's, to rounding
        assert _relative(_rebuilt(controller, kinematics, case, -1.0, EPS, 0.5 * eps),
                         ref) < ROUNDING
        # and that sign is what differs: beyond 100× the regularisation's 5·10⁻⁶ in every case
        differences.append(_relative(ours, ref))
        assert differences[-1] > 100 * EPS / 0.2
    assert np.median(differences) > 1e-2


def test_bad_input_exits_2_with_one_line(tmp_path):
    """Under any interpreter: a missing input file (or a missing package) is one line, code 2."""
    proc = _run_script(sys.executable, tmp_path / "absent.json", timeout=120.0)
    assert proc.returncode == 2 and proc.stdout == ""
    assert len(proc.stderr.strip().splitlines()) == 1 and "reference_actions:" in proc.stderr


@pytest.mark.parametrize("edit, message", [
    (lambda p: p.pop("cases"), "lacks ['cases']"),
    (lambda p: p["cases"][0].update(q=[0.0] * 3), "cases[0].q must be 7 finite numbers"),
    (lambda p: p["cases"][0].update(radii=[0.1, -0.1]), "radii must be positive"),
    (lambda p: p["spheres"][0].update(offset=[0.0, 0.1, 0.0]), "at link origins"),
    (lambda p: p["spheres"][0].update(link="no_such_link"), "'no_such_link'] not a link of"),
    (lambda p: p.update(q_min="low"), "q_min must be"),
])
def test_bad_cases_exit_2_with_one_line(reference_python, robot_spec, kinematics, tmp_path,
                                        edit, message):
    payload = _payload(robot_spec, _cases(robot_spec, kinematics)[:1])
    edit(payload)
    path = tmp_path / "cases.json"
    path.write_text(json.dumps(payload))
    proc = _run_script(reference_python, path, timeout=120.0)
    assert proc.returncode == 2 and proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines

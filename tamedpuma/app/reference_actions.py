"""The reference planner's joint accelerations (the GPL ``fabrics`` package by Spahn et al.) on
given states, for comparison with our vanilla fabric (``tests/test_reference_action.py``).

A standalone script for the *reference* venv (``fabrics``, ``forwardkinematics``, ``mpscenes``,
casadi, numpy; no tamedpuma): nothing in our package imports it. It only *calls* the package's
public API (``ParameterizedFabricPlanner.set_components`` / ``concretize`` / ``compute_action``,
``GenericURDFFk.numpy``); none of its code is copied here::

    REF_PYTHON tamedpuma/app/reference_actions.py --input cases.json

The input JSON::

    {"urdf_path": str (or "urdf": the URDF text), "root_link": str, "ee_link": str,
     "q_min": [rad]*dof, "q_max": [rad]*dof,
     "spheres": [{"link": str, "radius": m}, ...],    # body spheres at the link origins
     "goal_weight": float, "n_obstacles": int,
     "cases": [{"q": [rad]*dof, "qd": [rad/s]*dof, "goal_position": [m]*3,
                "centers": [[m]*3]*n_obstacles, "radii": [m]*n_obstacles}, ...]}

The planner is built once with the package's default parameters (its ``FabricPlannerConfig``):
a goal attractor on the end effector's position (relative to ``root_link``), every body sphere
against every obstacle sphere, both limits of every joint, speed control. Per case it prints
nothing but collects::

    {"action": [rad/s²]*dof,          # compute_action(q, qdot, goal, obstacles, radii)
     "ee_position": [m]*3,            # the package's forward kinematics of ee_link
     "sphere_centers": [[m]*3]*k}     # ... of every body sphere's link

and writes one JSON object to stdout at the end: ``{"fabrics_version": str, "cases": [...]}``.
``compute_action`` returns zero where the action's norm is below 1e-6 or above 1e6 (the
package's own rule); the caller checks for that. Everything the package prints goes to stderr.
Exit code 2 with a one-line message on a bad input or a missing package.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
import warnings
from pathlib import Path
from xml.etree import ElementTree

import numpy as np


class InputError(ValueError):
    """A malformed input file (reported in one line, exit code 2)."""


def _vector(value, size: int, what: str) -> np.ndarray:
    """``value`` as a finite float vector of length ``size``, else :class:`InputError`."""
    try:
        out = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be {size} numbers, got {value!r}") from None
    if out.shape != (size,) or not np.all(np.isfinite(out)):
        raise InputError(f"{what} must be {size} finite numbers, got {value!r}")
    return out


def _check_case(i: int, case: dict, dof: int, n_obstacles: int) -> dict:
    """One case with its arrays checked (shapes, finiteness, positive radii)."""
    if not isinstance(case, dict):
        raise InputError(f"cases[{i}] must be an object, got {case!r}")
    missing = sorted({"q", "qd", "goal_position", "centers", "radii"} - set(case))
    if missing:
        raise InputError(f"cases[{i}] lacks {missing}")
    centers = case["centers"]
    if not isinstance(centers, list) or len(centers) != n_obstacles:
        raise InputError(f"cases[{i}].centers must list {n_obstacles} centers (n_obstacles)")
    radii = _vector(case["radii"], n_obstacles, f"cases[{i}].radii")
    if np.any(radii <= 0):
        raise InputError(f"cases[{i}].radii must be positive, got {radii.tolist()}")
    return {"q": _vector(case["q"], dof, f"cases[{i}].q"),
            "qd": _vector(case["qd"], dof, f"cases[{i}].qd"),
            "goal_position": _vector(case["goal_position"], 3, f"cases[{i}].goal_position"),
            "centers": [_vector(c, 3, f"cases[{i}].centers[{j}]") for j, c in enumerate(centers)],
            "radii": radii}


def _check_links(spec: dict) -> None:
    """Every link the input names (root, end effector, spheres) is a link of its URDF."""
    try:
        links = {link.get("name") for link in ElementTree.fromstring(spec["urdf"]).iter("link")}
    except ElementTree.ParseError as exc:
        raise InputError(f"the URDF does not parse: {exc}") from None
    named = [spec["root_link"], spec["ee_link"]] + [
        s.get("link") if isinstance(s, dict) else s for s in spec["spheres"]]
    unknown = [name for name in named if name not in links]
    if unknown:
        raise InputError(f"{unknown} not a link of the URDF; its links: {sorted(links)}")


def load_input(path: Path) -> dict:
    """The checked input (see the module doc), with the URDF text under ``"urdf"``."""
    try:
        spec = json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path} is not JSON: {exc}") from None
    if not isinstance(spec, dict):
        raise InputError(f"{path} must hold a JSON object")
    missing = sorted({"root_link", "ee_link", "q_min", "q_max", "spheres", "goal_weight",
                      "n_obstacles", "cases"} - set(spec))
    if missing:
        raise InputError(f"the input lacks {missing}")
    if "urdf" not in spec:
        if "urdf_path" not in spec:
            raise InputError("the input needs urdf (the URDF text) or urdf_path")
        spec["urdf"] = Path(spec["urdf_path"]).read_text()
    _check_links(spec)
    dof = len(spec["q_min"])
    spec["q_min"] = _vector(spec["q_min"], dof, "q_min")
    spec["q_max"] = _vector(spec["q_max"], dof, "q_max")
    if not np.all(spec["q_min"] < spec["q_max"]):
        raise InputError("q_min must be below q_max in every joint")
    for s in spec["spheres"]:
        if not (isinstance(s, dict) and isinstance(s.get("link"), str)
                and float(s.get("radius", 0)) > 0):
            raise InputError(f"each sphere needs a link name and a radius > 0, got {s!r}")
        if any(float(v) != 0.0 for v in s.get("offset", (0, 0, 0))):
            raise InputError(f"sphere {s!r}: the reference's body spheres sit at link origins")
    n = spec["n_obstacles"]
    if not isinstance(n, int) or n < 0:
        raise InputError(f"n_obstacles must be a non-negative integer, got {n!r}")
    if not isinstance(spec["cases"], list) or not spec["cases"]:
        raise InputError("cases must be a non-empty list")
    spec["cases"] = [_check_case(i, c, dof, n) for i, c in enumerate(spec["cases"])]
    return spec


def build_planner(spec: dict):
    """(planner, forward kinematics) of the reference planner with its default parameters."""
    from fabrics.planner.parameterized_planner import ParameterizedFabricPlanner
    from forwardkinematics.urdfFks.generic_urdf_fk import GenericURDFFk
    from mpscenes.goals.goal_composition import GoalComposition

    fk = GenericURDFFk(spec["urdf"], root_link=spec["root_link"], end_links=[spec["ee_link"]])
    goal = GoalComposition(name="goal", content_dict={"subgoal0": {
        "weight": float(spec["goal_weight"]), "is_primary_goal": True, "indices": [0, 1, 2],
        "parent_link": spec["root_link"], "child_link": spec["ee_link"],
        "desired_position": [0.0, 0.0, 0.0], "epsilon": 0.05, "type": "staticSubGoal"}})
    planner = ParameterizedFabricPlanner(len(spec["q_min"]), fk)
    planner.set_components(collision_links=[s["link"] for s in spec["spheres"]], goal=goal,
                           limits=np.column_stack((spec["q_min"], spec["q_max"])).tolist(),
                           number_obstacles=int(spec["n_obstacles"]))
    planner.concretize()
    return planner, fk


def case_result(planner, fk, spec: dict, case: dict) -> dict:
    """The reference's action and forward kinematics at one case (see the module doc)."""
    kwargs = {"q": case["q"], "qdot": case["qd"], "x_goal_0": case["goal_position"],
              "weight_goal_0": float(spec["goal_weight"])}
    for sphere in spec["spheres"]:
        kwargs[f"radius_body_{sphere['link']}"] = float(sphere["radius"])
    for j, (center, radius) in enumerate(zip(case["centers"], case["radii"])):
        kwargs[f"x_obst_{j}"] = center
        kwargs[f"radius_obst_{j}"] = float(radius)
    action = np.asarray(planner.compute_action(**kwargs), dtype=float).ravel()

    def position(link):
        return np.asarray(fk.numpy(case["q"], link, position_only=True), float).ravel().tolist()

    return {"action": action.tolist(), "ee_position": position(spec["ee_link"]),
            "sphere_centers": [position(s["link"]) for s in spec["spheres"]]}


def _version(package: str) -> str:
    """The installed version of ``package``, or "unknown"."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:
        return "unknown"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--input", type=Path, required=True, help="the cases JSON")
    args = parser.parse_args(argv)
    logging.disable(logging.WARNING)  # the package warns on every near-zero action
    warnings.simplefilter("ignore", FutureWarning)  # casadi's numpy-interop notice
    try:
        import fabrics  # noqa: F401  (fail early, in one line, where it is missing)
        spec = load_input(args.input)
    except (ImportError, OSError, ValueError, TypeError, KeyError) as exc:  # InputError too
        print(f"reference_actions: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    from forwardkinematics.urdfFks.urdfFk import LinkNotInURDFError

    with contextlib.redirect_stdout(sys.stderr):  # the packages print progress to stdout
        try:
            planner, fk = build_planner(spec)
        except LinkNotInURDFError as exc:
            print(f"reference_actions: {' '.join(str(exc).split())}", file=sys.stderr)
            return 2
        cases = [case_result(planner, fk, spec, case) for case in spec["cases"]]
    print(json.dumps({"fabrics_version": _version("fabrics"), "cases": cases}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

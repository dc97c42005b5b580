"""Read the project's YAML config groups without Hydra (for tests, benchmarks and library use).

Entry points compose configs with Hydra; library code receives the schema's typed objects
(``tamedpuma/app/schema.py``). This module loads one group option of the package's ``conf/``
(:data:`tamedpuma.paths.CONF_DIR`) as a plain dict (:func:`load_group`) and types the robot and
scenario groups (:func:`robot_config`, :func:`typed_scenario`).
"""

from __future__ import annotations

import functools
from pathlib import Path

from omegaconf import OmegaConf

from tamedpuma.app import schema as _schema  # also registers the config schema with Hydra
from tamedpuma.errors import ConfigError
from tamedpuma.paths import CONF_DIR  # noqa: E402 - tamedpuma/conf (package data)


def config_roots() -> list[Path]:
    """The config folders the entry points search: the package's ``conf/``, then the installed
    method plugins' folders (:func:`tamedpuma.methods.config_dirs`)."""
    from tamedpuma.methods import config_dirs

    return [CONF_DIR, *config_dirs()]


def group_options(group: str, extra_dirs: tuple[Path, ...] = ()) -> list[str]:
    """Every option of config group ``group``, nested ones included (``tomato/00``), in the
    package's ``conf/``, the method plugins' folders and ``extra_dirs`` (a user's
    ``--config-dir``), sorted."""
    found = set()
    for root in (*config_roots(), *extra_dirs):
        found.update(options_in(Path(root) / group))
    return sorted(found)


def options_in(folder: Path) -> list[str]:
    """The options (``*.yaml`` below ``folder``, nested ones as ``tomato/00``) of one config
    group folder, sorted; none if it is missing."""
    if not folder.is_dir():
        return []
    return sorted(p.relative_to(folder).with_suffix("").as_posix() for p in folder.rglob("*.yaml"))


def load_group(group: str, name: str) -> dict:
    """Load ``conf/<group>/<name>.yaml`` (or a method plugin's) as a plain dict (interpolations
    left unresolved)."""
    paths = [root / group / f"{name}.yaml" for root in config_roots()]
    path = next((p for p in paths if p.is_file()), paths[0])
    if not path.is_file():
        raise ConfigError(f"unknown {group} {name!r}; choose one of "
                          f"{', '.join(group_options(group))}")
    return OmegaConf.to_container(OmegaConf.load(path), resolve=False)


def robot_config(name: str) -> _schema.RobotSchema:
    """The robot option ``conf/robot/<name>.yaml`` as the sweep sees it: its ``defaults`` (a
    derived option's base robot) merged under its own keys, then typed by the schema
    (:class:`~tamedpuma.app.schema.RobotSchema`: checked, every default filled in)."""
    own = load_group("robot", name)
    merged = OmegaConf.create({})
    for base in own.pop("defaults", []):
        if base != "_self_":
            merged = OmegaConf.merge(merged, robot_config(str(base)))
    merged = OmegaConf.merge(merged, own)
    return _schema.typed(_schema.RobotSchema, merged, "robot")


def typed_scenario(cfg):
    """A scenario mapping (e.g. :func:`load_group` ``("scenario", name)`` with its goal filled
    in) typed by the schema (:class:`~tamedpuma.app.schema.ScenarioSchema`), as
    :func:`tamedpuma.worlds.scenarios.scenario_from_config` takes it."""
    return _schema.typed(_schema.ScenarioSchema, cfg, "scenario")


def start_options(robot: str = "iiwa14") -> dict:
    """The keyword arguments of :func:`tamedpuma.worlds.scenarios.scenario_from_config` that a
    run of the default config passes for ``robot``: seed 0 and the robot's start clamp."""
    cfg = robot_config(robot)
    return {"seed": _schema.RunConfig.seed, "limit_tolerance": cfg.limit_tolerance,
            "limit_margin": cfg.limit_margin}


def workspace_starts(task: dict) -> list[tuple[str, object, object, list | None, list | None]]:
    """The end-effector poses of the scenario starts a training checks against the task's
    workspace (:func:`tamedpuma.puma.pipeline.check_workspace`): ``task.workspace_check.scenarios``
    (``auto``: every ``conf/scenario/<task>/*.yaml``; or a list of scenario names / yaml paths)
    on the robot ``task.workspace_check.robot`` (:func:`robot_config`). Per start: (name,
    position [m], quaternion (x, y, z, w), the scenario's goal position and quaternion, or None
    where it leaves them to the task). None with ``action: off``; scenarios that generate their
    starts are left out (checked where the starts are made)."""
    import numpy as np

    from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config

    wc = task["workspace_check"]
    if wc["action"] == "off":
        return []
    names = wc["scenarios"]
    if names == "auto":
        files = sorted((CONF_DIR / "scenario" / str(task["name"])).glob("*.yaml"))
    else:
        files = [Path(n) if str(n).endswith(".yaml") else CONF_DIR / "scenario" / f"{n}.yaml"
                 for n in (names or [])]
    if not files:
        return []
    kin = Kinematics(robot_spec_from_config(robot_config(str(wc["robot"]))))
    out = []
    for f in files:
        if not f.is_file():
            raise ConfigError(f"task.workspace_check.scenarios: no scenario file {f}")
        sc = OmegaConf.to_container(OmegaConf.load(f), resolve=False)
        goal = sc.get("goal") or {}
        gp, gq = goal.get("position"), goal.get("quaternion")
        if sc.get("generator") or (sc.get("q0") is None and kin.spec.home is None):
            continue
        p, q = kin.ee_pose(np.asarray(sc["q0"] if sc.get("q0") is not None else kin.spec.home,
                                      float))
        out.append((str(sc.get("name", f.stem)), p, q, gp if isinstance(gp, list) else None,
                    gq if isinstance(gq, list) else None))
    return out


def table1_starts(task: str) -> list[list[float]]:
    """The start configurations q0 [rad] of the task's Table-1 scenarios
    (``conf/scenario/<task>/NN.yaml``); empty for a task without them."""
    return [list(q0) for q0 in _table1_starts(task)]


@functools.cache
def _table1_starts(task: str) -> tuple[tuple[float, ...], ...]:
    """:func:`table1_starts`, read once per process (a sweep's worker builds hundreds of random
    scenarios; reading the 15 files took 0.2 s of each)."""
    folder = CONF_DIR / "scenario" / task
    return tuple(tuple(float(v) for v in OmegaConf.load(p)["q0"])
                 for p in sorted(folder.glob("[0-9][0-9].yaml")))


def default_kinematics():
    """A :class:`~tamedpuma.robot.kinematics.Kinematics` of the default robot (iiwa14)."""
    from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config

    return Kinematics(robot_spec_from_config(robot_config("iiwa14")))

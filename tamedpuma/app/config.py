"""Read the project's YAML config groups without Hydra (for tests, benchmarks and library use).

Entry points compose configs with Hydra; library code receives plain mappings. This module finds
the top-level ``conf/`` folder of the checkout and loads one group option as a plain dict.
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import OmegaConf

from tamedpuma.app import schema as _schema  # noqa: F401 - registers the config schema with Hydra
from tamedpuma.errors import ConfigError

CONF_DIR = Path(__file__).resolve().parent.parent / "conf"  # tamedpuma/conf (package data)


def load_group(group: str, name: str) -> dict:
    """Load ``conf/<group>/<name>.yaml`` as a plain dict (interpolations left unresolved)."""
    path = CONF_DIR / group / f"{name}.yaml"
    if not path.is_file():
        options = sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))
        raise ConfigError(f"unknown {group} {name!r}; choose one of {options}")
    return OmegaConf.to_container(OmegaConf.load(path), resolve=False)


def default_kinematics():
    """A :class:`~tamedpuma.robot.kinematics.Kinematics` of the default robot (iiwa14)."""
    from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config

    return Kinematics(robot_spec_from_config(load_group("robot", "iiwa14")))

"""The control methods. Each lives in ``tamedpuma/methods/<name>.py`` and exposes

    make(cfg: Mapping, kinematics: Kinematics) -> Controller

where ``cfg`` is the plain content of ``conf/method/<name>.yaml`` (without the optional
``label``, the name a configured variant carries in tables, e.g. ``conf/method/cpm_literal.yaml``).
Methods never import the simulator; they see only :class:`~tamedpuma.types.Observation` and return
:class:`~tamedpuma.types.Command`.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Mapping

from tamedpuma.errors import ConfigError
from tamedpuma.robot.kinematics import Kinematics
from tamedpuma.types import Controller


def available() -> list[str]:
    """Names of the methods found in this package."""
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def make(name: str, cfg: Mapping, kinematics: Kinematics) -> Controller:
    """Build the controller of method ``name`` from its config, on the robot's controller body
    (its ``spheres`` and ``guard_spheres``: :meth:`RobotSpec.controller_body`)."""
    if name not in available():
        raise ConfigError(f"unknown method {name!r}; choose one of {available()}")
    module = importlib.import_module(f"tamedpuma.methods.{name}")
    body = kinematics.spec.controller_body()
    if body is not kinematics.spec:
        kinematics = Kinematics(body)
    return module.make({k: v for k, v in cfg.items() if k != "label"}, kinematics)

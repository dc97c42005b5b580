"""The control methods. Each lives in ``tamedpuma/methods/<name>.py`` and exposes

    SETTINGS: a frozen dataclass of the method's settings (their defaults the only defaults,
              their ranges checked in its constructor)
    make(settings: SETTINGS, kinematics: Kinematics) -> Controller

``method=<name>`` (``conf/method/<name>.yaml``) composes to exactly the settings' defaults
(``tests/test_method_settings.py``); a configured variant of a method, e.g.
``conf/method/cpm_literal.yaml``, overrides them. ``tamedpuma.app.schema`` types a composed
config into the settings (besides the method's ``name`` and ``label``, the name a variant
carries in tables), and the entry points pass them down. Methods never import the simulator;
they see only :class:`~tamedpuma.types.Observation` and return
:class:`~tamedpuma.types.Command`.

A method from another package registers the same way through the entry point group
``tamedpuma.methods`` (docs/extending.md, "A method from outside the package"): the entry point
names a :class:`MethodPlugin` (its ``make``, its settings dataclass and the folder holding its
``method/<name>.yaml``). The sweep, the recorders, the analysis and the replay then treat it as
one of their own.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import logging
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

from tamedpuma.errors import ConfigError
from tamedpuma.robot.kinematics import Kinematics
from tamedpuma.types import Controller

#: the entry point group a method from another package registers in
ENTRY_POINT_GROUP = "tamedpuma.methods"
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MethodPlugin:
    """A method from another package, as its entry point names it.

    name: the method's name (``method=<name>`` on the command line; its runs' ``method``);
    make: ``make(settings, kinematics) -> Controller``, settings an instance of ``settings``
    (fields ``task``, ``checkpoint`` and ``model`` make the sweep resolve and record a
    second-order PUMA model, as for the built-in learned methods, and pass its path as
    ``checkpoint``);
    settings: a (preferably frozen) dataclass of the method's options, their types and defaults
    (its ``__post_init__`` checks the ranges; a ``ValueError`` there is a one-line config
    error);
    config_dir: the folder holding ``method/<name>.yaml`` (added to Hydra's config search path
    by the entry points).
    """

    name: str
    make: Callable[[object, Kinematics], Controller]
    settings: type
    config_dir: Path

    def __post_init__(self):
        if not self.name.isidentifier():
            raise ConfigError(f"method plugin name {self.name!r} must be an identifier")
        if not callable(self.make):
            raise ConfigError(f"method plugin {self.name}: make is not callable")
        if not dataclasses.is_dataclass(self.settings):
            raise ConfigError(f"method plugin {self.name}: settings must be a dataclass")
        reserved = {f.name for f in dataclasses.fields(self.settings)} & {"name", "label"}
        if reserved:
            raise ConfigError(f"method plugin {self.name}: settings may not define "
                              f"{sorted(reserved)} (the schema's own keys)")
        object.__setattr__(self, "config_dir", Path(self.config_dir))
        if not (self.config_dir / "method" / f"{self.name}.yaml").is_file():
            raise ConfigError(f"method plugin {self.name}: no {self.config_dir}/method/"
                              f"{self.name}.yaml")


def builtin() -> list[str]:
    """Names of the methods of this package."""
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


@functools.cache
def plugins() -> dict[str, MethodPlugin]:
    """The methods registered by installed packages (entry point group ``tamedpuma.methods``),
    by name. A plugin that cannot be loaded, or whose name is taken, is left out with one
    warning naming it (the built-in methods still work)."""
    found: dict[str, MethodPlugin] = {}
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            plugin = ep.load()
            if callable(plugin) and not isinstance(plugin, MethodPlugin):
                plugin = plugin()
            if not isinstance(plugin, MethodPlugin):
                raise ConfigError(f"{ep.value} is not a tamedpuma.methods.MethodPlugin")
            if plugin.name in builtin() or plugin.name in found:
                raise ConfigError(f"the name {plugin.name!r} is taken")
        except Exception as exc:  # noqa: BLE001 - one broken plugin leaves the rest usable
            log.warning("method plugin %s (%s) not loaded: %s", ep.name, ep.value,
                        " ".join(str(exc).split()) or type(exc).__name__)
            continue
        found[plugin.name] = plugin
    return found


def available() -> list[str]:
    """Names of every method: this package's and the installed plugins'."""
    return sorted([*builtin(), *plugins()])


def config_dirs() -> list[Path]:
    """The plugins' config folders (each holds ``method/<name>.yaml``), in name order."""
    return [plugins()[name].config_dir for name in sorted(plugins())]


def settings_type(name: str) -> type:
    """The settings dataclass of method ``name`` (a plugin's ``settings``, else the module's
    ``SETTINGS``)."""
    if name not in available():
        raise ConfigError(f"unknown method {name!r}; choose one of {available()}")
    if name in plugins():
        return plugins()[name].settings
    return importlib.import_module(f"tamedpuma.methods.{name}").SETTINGS


def make(name: str, settings, kinematics: Kinematics) -> Controller:
    """Build the controller of method ``name`` from its settings (an instance of
    :func:`settings_type`), on the robot's controller body (its ``spheres`` and
    ``guard_spheres``: :meth:`RobotSpec.controller_body`)."""
    expected = settings_type(name)
    if not isinstance(settings, expected):
        raise TypeError(f"method {name} takes {expected.__qualname__} settings, got "
                        f"{type(settings).__qualname__}")
    body = kinematics.spec.controller_body()
    if body is not kinematics.spec:
        kinematics = Kinematics(body)
    if name in plugins():
        return plugins()[name].make(settings, kinematics)
    return importlib.import_module(f"tamedpuma.methods.{name}").make(settings, kinematics)


def puma_task(settings):
    """PUMA's task for a plugin driven by the trained primitive: the second-order model that
    ``settings.checkpoint`` names (the sweep sets it to the model it resolved and records) in its
    task adapter, :class:`~tamedpuma.methods._policy.PoseTask` for the arm. Its
    ``acceleration(state, qd, goal_position, goal_quaternion)`` gives PUMA's
    :class:`~tamedpuma.methods._policy.TaskAcceleration` ``(ẍ_d [m/s², rad/s²], J, J̇q̇)`` at a
    :class:`~tamedpuma.robot.kinematics.KinematicState`."""
    from tamedpuma.methods._learned import load_task

    return load_task(settings)

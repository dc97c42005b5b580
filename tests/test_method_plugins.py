"""Methods from other packages: the entry point group ``tamedpuma.methods``, the schema of a
plugin's settings, its config folder on the search path, and a broken plugin left out."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from tamedpuma import methods
from tamedpuma.app import cli, config, schema
from tamedpuma.errors import ConfigError
from tamedpuma.types import Command


@dataclass(frozen=True)
class HoldSettings:
    """A plugin's options: one gain with a range check."""

    gain: float = 2.0          # [1/s]
    joints: list[int] | None = None

    def __post_init__(self):
        if not self.gain > 0:
            raise ValueError(f"gain must be > 0, got {self.gain!r}")


class Hold:
    """q̈ = −k q̇: brakes every joint (the smallest real controller)."""

    def __init__(self, gain: float):
        self.gain = gain

    def reset(self, scenario) -> None:
        pass

    def step(self, obs) -> Command:
        return Command(qdd=-self.gain * np.asarray(obs.qd))


def _make(settings, kinematics):
    return Hold(float(settings.gain))


def _conf(tmp_path: Path, name: str = "hold") -> Path:
    (tmp_path / "method").mkdir(parents=True, exist_ok=True)
    (tmp_path / "method" / f"{name}.yaml").write_text(f"name: {name}\ngain: 3.0\n")
    return tmp_path


class _EntryPoint:
    def __init__(self, name, target, value="test_module:PLUGIN"):
        self.name, self.value, self._target = name, value, target

    def load(self):
        if isinstance(self._target, Exception):
            raise self._target
        return self._target


@pytest.fixture
def installed(monkeypatch):
    """Install entry points (a list of _EntryPoint) for the test; the registry is re-read."""
    def install(*entry_points):
        monkeypatch.setattr(metadata, "entry_points",
                            lambda group=None: list(entry_points)
                            if group == methods.ENTRY_POINT_GROUP else [])
        methods.plugins.cache_clear()
    yield install
    methods.plugins.cache_clear()


def test_a_plugin_is_a_method_like_the_built_in_ones(installed, tmp_path, kinematics):
    plugin = methods.MethodPlugin("hold", _make, HoldSettings, _conf(tmp_path))
    installed(_EntryPoint("hold", plugin))
    assert "hold" in methods.available() and set(methods.builtin()) < set(methods.available())
    typed = schema.typed(schema._plugin_schemas()["hold"],
                         {"name": "hold", "gain": 3.0, "label": "x"}, "method")
    settings = schema.method_settings(typed)  # what the plugin's make takes
    assert settings == HoldSettings(gain=3.0)
    controller = methods.make("hold", settings, kinematics)
    command = controller.step(type("Obs", (), {"qd": np.ones(7)})())
    np.testing.assert_allclose(command.qdd, -3.0 * np.ones(7))
    assert methods.config_dirs() == [tmp_path]
    assert "hold" in config.group_options("method")
    assert config.load_group("method", "hold") == {"name": "hold", "gain": 3.0}


def test_the_schema_types_and_checks_a_plugins_settings(installed, tmp_path):
    installed(_EntryPoint("hold", methods.MethodPlugin("hold", _make, HoldSettings,
                                                       _conf(tmp_path))))
    schemas = schema._plugin_schemas()
    typed = schema.typed(schemas["hold"], {"name": "hold", "gain": 5, "label": "mine"}, "method")
    assert (typed.name, typed.gain, typed.label, typed.joints) == ("hold", 5.0, "mine", None)
    with pytest.raises(ConfigError, match="method: gain must be > 0"):
        schema.typed(schemas["hold"], {"name": "hold", "gain": -1.0}, "method")
    with pytest.raises(ConfigError, match="gian"):
        schema.typed(schemas["hold"], {"name": "hold", "gian": 1.0}, "method")


def test_the_sweep_searches_the_plugins_config_folders(installed, tmp_path):
    installed(_EntryPoint("hold", methods.MethodPlugin("hold", _make, HoldSettings,
                                                       _conf(tmp_path))))
    argv = cli.with_plugin_configs(["-m", "method=hold", "hydra.searchpath=[file:///x]"])
    search = f"hydra.searchpath=['file://{tmp_path.resolve()}','file:///x']"
    assert argv == ["-m", search, "method=hold"]
    # Hydra's parser reads its overrides as one run of positionals: the search path joins that
    # run, never after a trailing flag such as `--cfg job`
    argv = cli.with_plugin_configs(["method=hold", "--cfg", "job"])
    assert argv == [f"hydra.searchpath=['file://{tmp_path.resolve()}']", "method=hold",
                    "--cfg", "job"]
    argv = cli.with_plugin_configs(["-m", "--cfg", "job"])
    assert argv == ["-m", "--cfg", "job", f"hydra.searchpath=['file://{tmp_path.resolve()}']"]
    installed()
    assert cli.with_plugin_configs(["method=fpm"]) == ["method=fpm"]


def test_a_broken_or_clashing_plugin_is_left_out_with_a_warning(installed, tmp_path, caplog):
    good = methods.MethodPlugin("hold", _make, HoldSettings, _conf(tmp_path))
    clash = methods.MethodPlugin("fpm", _make, HoldSettings, _conf(tmp_path, "fpm"))
    installed(_EntryPoint("broken", ImportError("No module named 'nothing'")),
              _EntryPoint("notaplugin", object()), _EntryPoint("fpm", clash),
              _EntryPoint("hold", good), _EntryPoint("hold2", good))
    assert set(methods.plugins()) == {"hold"}
    text = caplog.text
    assert "broken" in text and "nothing" in text and "notaplugin" in text
    assert "'fpm' is taken" in text and "'hold' is taken" in text


@pytest.mark.parametrize("kwargs, match", [
    ({"name": "no-dash"}, "identifier"),
    ({"settings": dict}, "dataclass"),
    ({"name": "other"}, "no .*other.yaml"),
    ({"make": None}, "not callable")])
def test_a_malformed_plugin_is_refused(tmp_path, kwargs, match):
    args = {"name": "hold", "make": _make, "settings": HoldSettings,
            "config_dir": _conf(tmp_path), **kwargs}
    with pytest.raises(ConfigError, match=match):
        methods.MethodPlugin(**args)

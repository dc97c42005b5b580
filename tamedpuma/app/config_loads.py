"""Config loading shared within a process, for the ``cores`` launcher
(``hydra_plugins/tamedpuma_launcher``): its workers, and the launching process that composes jobs
to validate them, compose every job of a sweep with the loader this module installs.

Hydra composes every job's config afresh (``ConfigLoaderImpl.load_sweep_config``): it reads and
parses each config file of the defaults list again (about 20 YAML files for a run), builds the
defaults list, merges the files and applies the overrides, 0.2-0.3 s per job. Two things make
that once-per-process work (a job then takes 0.015 s):

- :class:`SharedLoads`, a config repository that parses each file once per process and hands
  out copies.
- :class:`SweepConfigLoader`, the loader's ``load_sweep_config``. A job's overrides split into
  *plain values* (``scenario.random_seed=2051``, ``without_obstacles=true``: a change of a key
  that is no config group, no ``+``/``++``/``~``, no ``@package``, no sweep, not Hydra's own)
  and *structural* ones (the group selections ``task=``, ``method=``, ``+experiment=``, and
  Hydra's overrides), which decide the defaults list. Jobs of a sweep share a few structural
  selections (16 in the 6400 jobs of the randomized suite), so the loader composes each distinct
  one once per process with Hydra's own ``load_sweep_config``, keeps the result, and gives each
  job a deep copy with its plain values applied by Hydra's ``_apply_overrides_to_config`` (what
  Hydra does after composing) and with what Hydra derives from the whole override list
  rewritten (``hydra.overrides``, ``hydra.job.override_dirname``; the working directory, the
  ``env_copy`` variables and Hydra's version are read again, as Hydra reads them). A job
  with any other override (``+key=``, ``~key``, ...), or one whose fast path raises, is composed
  by Hydra in full, so a failing job fails with Hydra's own error. Every job's config is the one
  Hydra composes without this (tested field for field, ``tests/test_config_loads.py``).

This module is not in the ``hydra_plugins`` namespace on purpose: Hydra re-imports the modules
there when it rescans its plugins, which would give every job fresh copies of the per-process
tables (:data:`_LOADED`, :data:`_COMPOSED`).
"""

from __future__ import annotations

import copy
import os

from hydra._internal.config_loader_impl import ConfigLoaderImpl, get_overrides_dirname
from hydra._internal.config_repository import ConfigRepository, IConfigRepository
from hydra.core.object_type import ObjectType
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import OverrideType
from omegaconf import DictConfig, OmegaConf, open_dict

#: (the repository's sources, config path) -> the ConfigResult read, per process
_LOADED: dict[tuple, object] = {}

#: (config name, structural override lines, the repository's sources, job name, Hydra's version
#: base) -> that selection composed by Hydra, per process
_COMPOSED: dict[tuple, DictConfig] = {}
#: the most selections :data:`_COMPOSED` keeps (Table 1 has 240, the randomized suite 16)
COMPOSED_KEPT = 1024

#: (config name, Hydra's override lines, the repository's sources) -> the repository a job with
#: them composes from (``hydra.searchpath`` included) and its answers to ``group_exists``
_GROUPS: dict[tuple, tuple] = {}


class SharedLoads(IConfigRepository):
    """A config repository whose :meth:`load_config` answers from this process's
    :data:`_LOADED`, keyed by the search path, and delegates everything else.

    Each answer is a deep copy: Hydra's compose merges the loaded configs without copying them
    (its first one becomes the composed config's root), so a shared result would carry one
    job's values into the next. Copying a loaded result costs a third of reading it.

    Hydra wraps the repository in a per-compose cache that deep-copies it and re-initialises the
    copy's sources; the copy keeps sharing :data:`_LOADED`, and copies Hydra's repository
    shallowly (:meth:`__deepcopy__`)."""

    def __init__(self, inner: IConfigRepository):
        self._inner = inner
        self._sources: tuple | None = None  # the search path's key, until it changes

    def __deepcopy__(self, memo) -> SharedLoads:
        inner = self._inner
        if type(inner) is ConfigRepository:  # its one mutation, initialize_sources, replaces
            # its list of sources (which read and hold nothing a compose changes): a shallow
            # copy is as independent as Hydra's deep one, which copies the whole ConfigStore
            return SharedLoads(copy.copy(inner))
        return SharedLoads(copy.deepcopy(inner, memo))

    def _key(self, config_path: str) -> tuple:
        if self._sources is None:
            self._sources = tuple((s.provider, s.path) for s in self._inner.get_sources())
        return (self._sources, config_path)

    def load_config(self, config_path: str):
        key = self._key(config_path)
        if key not in _LOADED:
            _LOADED[key] = self._inner.load_config(config_path)
        return copy.deepcopy(_LOADED[key])

    def get_schema_source(self):
        return self._inner.get_schema_source()

    def group_exists(self, config_path: str) -> bool:
        return self._inner.group_exists(config_path)

    def config_exists(self, config_path: str) -> bool:
        return self._inner.config_exists(config_path)

    def get_group_options(self, group_name: str,
                          results_filter: ObjectType | None = ObjectType.CONFIG) -> list[str]:
        return self._inner.get_group_options(group_name, results_filter)

    def get_sources(self):
        return self._inner.get_sources()

    def initialize_sources(self, config_search_path) -> None:
        self._inner.initialize_sources(config_search_path)
        self._sources = None


class SweepConfigLoader(ConfigLoaderImpl):
    """Hydra's config loader whose :meth:`load_sweep_config` composes each distinct structural
    selection once per process (:data:`_COMPOSED`) and applies a job's plain values to a copy of
    it (the module docstring). Everything else is Hydra's. It holds no state of its own, so
    :func:`share_loads` installs it on the loader Hydra made by changing that object's class."""

    def load_sweep_config(self, master_config: DictConfig,
                          sweep_overrides: list[str]) -> DictConfig:
        try:
            cfg = self._from_composed(master_config, list(sweep_overrides))
        except Exception:  # Hydra's own compose raises the job's error (or composes it)
            cfg = None
        if cfg is None:
            return super().load_sweep_config(master_config, sweep_overrides)
        return cfg

    def _sources(self) -> tuple:
        return tuple((s.provider, s.path) for s in self.repository.get_sources())

    def _is_group(self, config_name, hydra_lines: list[str]):
        """``group_exists`` of the repository a job with Hydra's overrides ``hydra_lines``
        composes from (the loader's, with the folders of a ``hydra.searchpath``), memoised."""
        key = (config_name, tuple(hydra_lines), self._sources())
        if key not in _GROUPS:
            _, repo = self._parse_overrides_and_create_caching_repo(config_name, hydra_lines)
            _GROUPS[key] = (repo, {})
        repo, known = _GROUPS[key]

        def is_group(path: str) -> bool:
            if path not in known:
                known[path] = repo.group_exists(path)
            return known[path]

        return is_group

    def _from_composed(self, master_config: DictConfig,
                       sweep_overrides: list[str]) -> DictConfig | None:
        """The job's config from its structural selection composed once, or None when an
        override is neither a plain value nor a structural one (Hydra composes the job)."""
        from hydra import __version__, version
        from hydra.core.utils import JobRuntime

        config_name = master_config.hydra.job.config_name
        master_lines = OmegaConf.to_container(master_config.hydra.overrides.hydra)
        # what ConfigLoaderImpl.load_sweep_config composes
        parsed = OverridesParser.create().parse_overrides(
            overrides=list(master_lines) + sweep_overrides)
        if not all(o.is_hydra_override() for o in parsed[:len(master_lines)]):
            return None
        hydra_lines = [o.input_line for o in parsed if o.is_hydra_override()]
        is_group = self._is_group(config_name, hydra_lines)
        structural, plain, task = [], [], []
        for o in parsed[len(master_lines):]:
            if not o.is_hydra_override():
                task.append(o)
            if o.is_hydra_override() or _is_group_selection(o, is_group):
                structural.append(o.input_line)
            elif _is_plain_value(o, is_group):
                plain.append(o)
            else:
                return None

        key = (config_name, tuple(master_lines), tuple(structural), self._sources(),
               JobRuntime().get("name"), str(version.getbase()))
        if key not in _COMPOSED:
            if len(_COMPOSED) >= COMPOSED_KEPT:  # the oldest selection makes room
                _COMPOSED.pop(next(iter(_COMPOSED)))
            _COMPOSED[key] = super().load_sweep_config(master_config, structural)
        cfg = copy.deepcopy(_COMPOSED[key])

        # what ConfigLoaderImpl._load_configuration_impl does after composing
        ConfigLoaderImpl._apply_overrides_to_config(plain, cfg)
        # Hydra's own overrides are all structural: their lines are the composed ones again
        _replace_tail(cfg.hydra.overrides.hydra, len(hydra_lines), hydra_lines)
        _replace_tail(cfg.hydra.overrides.task, len(task) - len(plain),
                      [o.input_line for o in task])
        with open_dict(cfg.hydra):
            for env_key in cfg.hydra.job.env_copy:
                cfg.hydra.job.env_set[env_key] = os.environ[env_key]
        cfg.hydra.runtime.version = __version__
        cfg.hydra.runtime.version_base = version.getbase()
        cfg.hydra.runtime.cwd = os.getcwd()
        dirname = cfg.hydra.job.config.override_dirname
        cfg.hydra.job.override_dirname = get_overrides_dirname(
            overrides=task, kv_sep=dirname.kv_sep, item_sep=dirname.item_sep,
            exclude_keys=dirname.exclude_keys)
        OmegaConf.copy_cache(from_config=master_config, to_config=cfg)
        return cfg


def _is_plain_value(override, is_group) -> bool:
    """A change of a config value: no ``+``/``++``/``~``, no ``@package``, no sweep, and its key
    (also read with dots as slashes) is no config group."""
    key = override.key_or_group
    return (not override.is_hydra_override() and override.type == OverrideType.CHANGE
            and override.package is None and not override.is_sweep_override()
            and not is_group(key) and not is_group(key.replace(".", "/")))


def _is_group_selection(override, is_group) -> bool:
    """An override Hydra's defaults list takes as a config group's (``method=cpm``,
    ``+experiment=random``, ``~disturbance``): its key is a group and its value no dict."""
    return (not override.is_sweep_override() and not override.is_force_add()
            and is_group(override.key_or_group) and not isinstance(override.value(), dict))


def _replace_tail(lines, n_old: int, new: list[str]) -> None:
    """The last ``n_old`` entries of the list node ``lines`` replaced by ``new``."""
    for _ in range(n_old):
        lines.pop()
    for line in new:
        lines.append(line)


def share_loads(config_loader) -> None:
    """Make ``config_loader`` read through this process's shared results and compose sweep jobs
    from this process's composed selections; a copy of it (the one each job receives, pickled)
    uses the tables of its own process.

    Hydra makes the loader (a ``ConfigLoaderImpl``) and hands the same object to the sweeper,
    to the launcher's ``HydraContext`` and to ``GlobalHydra``; changing the object's class to
    :class:`SweepConfigLoader` changes it for every holder, with no reference to replace, and
    keeps all its attributes valid (the subclass adds none). A pickled copy names the subclass,
    so every worker's copy is one too. A loader of any other class keeps its class."""
    if not isinstance(config_loader.repository, SharedLoads):
        config_loader.repository = SharedLoads(config_loader.repository)
    if type(config_loader) is ConfigLoaderImpl:
        config_loader.__class__ = SweepConfigLoader

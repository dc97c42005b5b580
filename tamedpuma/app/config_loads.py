"""A Hydra config repository that reads each config file once per process: the workers of the
``cores`` launcher (``hydra_plugins/tamedpuma_launcher``) compose every job of a sweep with it.

Hydra composes every job's config afresh in the worker that runs it, and every compose reads and
parses each config file of the defaults list again (about 20 YAML files for a run): 0.25-0.3 s
of a Table-1 job, a quarter of what a short episode costs. The files do not change during a
sweep, so a process parses each once and hands out copies (a compose takes 0.16 s instead of
0.24 s); the compose (defaults list, merge, overrides) still runs per job, so every job's config
is the one Hydra composes without this (tested field for field).

This module is not in the ``hydra_plugins`` namespace on purpose: Hydra re-imports the modules
there when it rescans its plugins, which would give every job a fresh copy of the shared reads.
"""

from __future__ import annotations

import copy

from hydra._internal.config_repository import IConfigRepository
from hydra.core.object_type import ObjectType

#: (the repository's sources, config path) -> the ConfigResult read, per process
_LOADED: dict[tuple, object] = {}


class SharedLoads(IConfigRepository):
    """A config repository whose :meth:`load_config` answers from this process's
    :data:`_LOADED`, keyed by the search path, and delegates everything else.

    Each answer is a deep copy: Hydra's compose merges the loaded configs without copying them
    (its first one becomes the composed config's root), so a shared result would carry one
    job's values into the next. Copying a loaded result costs a third of reading it.

    Hydra wraps the repository in a per-compose cache that deep-copies it and re-initialises the
    copy's sources; the copy keeps sharing :data:`_LOADED`."""

    def __init__(self, inner: IConfigRepository):
        self._inner = inner

    def __deepcopy__(self, memo) -> SharedLoads:
        return SharedLoads(copy.deepcopy(self._inner, memo))

    def _key(self, config_path: str) -> tuple:
        return (tuple((s.provider, s.path) for s in self._inner.get_sources()), config_path)

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


def share_loads(config_loader) -> None:
    """Make ``config_loader`` read through this process's shared results; a copy of it (the
    one each job receives, pickled) reads through the shared results of its own process."""
    if not isinstance(config_loader.repository, SharedLoads):
        config_loader.repository = SharedLoads(config_loader.repository)

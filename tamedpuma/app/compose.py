"""The one place that composes a config with Hydra's compose API.

Every entry point other than the sweep's own ``@hydra.main`` (:mod:`tamedpuma.app.sweep`) gets
its config here: ``conf/<name>.yaml`` (:data:`tamedpuma.paths.CONF_DIR`) with Hydra overrides.

- :func:`session`: Hydra initialized on ``conf/`` for a block (the global state cleared before
  and after), for many compositions in a row (:func:`tamedpuma.app.cli.precheck_overrides`).
- :func:`compose`: one composition as a ``DictConfig``, inside the Hydra already initialized (an
  open :func:`session`, or the sweep's own app inside one of its jobs: its search path, a user's
  ``--config-dir`` included), else in a session of its own.
- :func:`compose_typed`: one composition typed by its schema (``sweep``, ``train``,
  ``body_model``: :data:`tamedpuma.app.schema.CONFIGS`), what library code receives.
- :func:`compose_dict`: one composition as a plain dict, ``train`` and ``body_model`` typed by
  their schema first (every key, the schema's defaults filled in): for what is stored or passed
  on as data (a checkpoint's recorded config, a sweep config the sweep's ``build`` types).
  In both a Hydra error becomes one line (:func:`hydra_error_line`) in a
  :class:`~tamedpuma.errors.ConfigError`.

A test (``tests/test_architecture.py``) keeps Hydra's compose and initialize API out of every
other module.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from tamedpuma.app.config import group_options
from tamedpuma.errors import ConfigError
from tamedpuma.paths import CONF_DIR


@contextmanager
def session(shared_reads: bool = False) -> Iterator[None]:
    """Hydra initialized on the package's ``conf/`` for the block; cleared before and after
    (whatever was initialized before is gone). ConfigError if the folder is missing.
    ``shared_reads``: its composes read each config file once, as the ``cores`` launcher's
    workers do (:mod:`tamedpuma.app.config_loads`)."""
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    if not CONF_DIR.is_dir():
        raise ConfigError(f"config folder not found: {CONF_DIR}")
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            if shared_reads:
                from tamedpuma.app.config_loads import share_loads

                share_loads(GlobalHydra.instance().config_loader())
            yield
    finally:
        GlobalHydra.instance().clear()


def compose(config_name: str, overrides: Sequence[str] = (), *, hydra_config: bool = False):
    """``conf/<config_name>.yaml`` with ``overrides`` as Hydra composes it (a ``DictConfig``,
    interpolations unresolved; ``hydra_config``: with Hydra's own ``hydra`` node, as a sweep's
    worker composes a job). Inside the Hydra already initialized, else in a :func:`session` of
    its own. Hydra's and OmegaConf's errors pass through (:func:`hydra_error_line` folds one)."""
    from hydra import compose as hydra_compose
    from hydra.core.global_hydra import GlobalHydra

    overrides = with_plugins(overrides)
    if GlobalHydra.instance().is_initialized():
        return hydra_compose(config_name, overrides=list(overrides),
                             return_hydra_config=hydra_config)
    with session():
        return hydra_compose(config_name, overrides=list(overrides),
                             return_hydra_config=hydra_config)


def with_plugins(overrides: Sequence[str]) -> list[str]:
    """``overrides`` with the installed method plugins' config folders
    (:func:`tamedpuma.methods.config_dirs`) in their ``hydra.searchpath``, so ``method=<plugin>``
    composes in every entry point as in the sweep; unchanged without plugins."""
    from tamedpuma.methods import config_dirs

    dirs = [f"file://{d.resolve()}" for d in config_dirs()]
    if not dirs:
        return list(overrides)
    from tamedpuma.app.cli import with_search_path

    return with_search_path(list(overrides), dirs)


def compose_typed(config_name: str, overrides: Sequence[str] = ()):
    """:func:`compose` typed by the schema (:data:`tamedpuma.app.schema.CONFIGS`: types, unknown
    keys and ranges checked, every default filled in); Hydra errors → ConfigError (one line)."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from tamedpuma.app import schema

    try:
        with session():
            return schema.CONFIGS[config_name](compose(config_name, overrides))
    except (HydraException, OmegaConfBaseException) as exc:
        raise ConfigError(hydra_error_line(exc)) from None


def compose_dict(config_name: str, overrides: Sequence[str] = ()) -> dict:
    """:func:`compose` → plain dict; Hydra errors → ConfigError (one line). ``train`` and
    ``body_model`` are checked against their schema (types, unknown keys, ranges) and come back
    complete (every key, schema defaults filled in); ``sweep`` comes back as composed, resolved
    (:func:`tamedpuma.app.sweep.build` types it)."""
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    from tamedpuma.app import schema

    try:
        with session():
            cfg = compose(config_name, overrides)
            if config_name in schema.CONFIGS and config_name != "sweep":  # typed: complete
                return schema.as_dict(schema.CONFIGS[config_name](cfg))  # (build types a sweep's)
            return OmegaConf.to_container(cfg, resolve=True)
    except (HydraException, OmegaConfBaseException) as exc:
        raise ConfigError(hydra_error_line(exc)) from None


_NOISE = ("full_key:", "object_type", "reference_type", "Config search path",
          "Set the environment variable HYDRA_FULL_ERROR")


def one_line(exc: BaseException) -> str:
    """A Hydra/OmegaConf error (often several lines) folded into one line, noise removed."""
    lines = []
    for raw in str(exc).splitlines():
        text = raw.strip()
        if not text:
            continue
        if text.startswith(_NOISE):
            if text.startswith("Config search path"):
                break
            continue
        if raw[:1].isspace() and lines and lines[-1].endswith(":"):
            lines[-1] += " " + text  # first item of an indented list
        elif raw[:1].isspace() and lines:
            lines[-1] += ", " + text
        else:
            lines.append(text)
    return " ".join(lines) or type(exc).__name__


def hydra_error_line(exc: BaseException, search: Sequence[str] = ()) -> str:
    """A Hydra composition error as one line; an unknown group option lists every option, and
    "Error merging override k=v" says why (its cause: e.g. "'abc' ... could not be converted to
    Float")."""
    line = _all_options(one_line(exc), list(search))
    cause = exc.__cause__
    if line.startswith("Error merging override") and cause is not None:
        line = f"{line}: {one_line(cause)}"
    return line


def _all_options(message: str, search: list[str]) -> str:
    """Hydra's "Could not find 'scenario/x' Available options in 'scenario': default, ..." lists
    only a group's top level; this lists every option, nested ones (``tomato/00``) included."""
    missing = re.search(r"Could not find '([^']+)'", message)
    listed = re.search(r"Available options in '([^']+)':", message)
    if not (missing and listed):
        return message
    group = listed.group(1)
    extra = tuple(Path(s.removeprefix("file://")) for s in search if s.startswith("file://"))
    options = group_options(group, extra)
    return (f"{message[:listed.start()].rstrip()} Available options in '{group}': "
            f"{', '.join(options)}")

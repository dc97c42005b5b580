"""Shared by the Hydra entry points (sweep, train): one-line errors and an override pre-check.

Hydra reports a bad override over several lines with a hint about HYDRA_FULL_ERROR. Before Hydra
runs, :func:`precheck_overrides` composes the config once per value of every sweep list and turns
the first problem into one line; it also checks that ``output_root`` can be written.

A user's own config folder works the Hydra way: ``--config-dir DIR`` (``-cd DIR``) and
``hydra.searchpath=[file://DIR]`` add DIR to the config search path, so its ``task/``,
``scenario/``, ``robot/``... options are found next to the shipped ones (:func:`split_argv`).
The installed method plugins' folders are added the same way (:func:`with_plugin_configs`).
"""

from __future__ import annotations

import functools
import re
import sys
from collections.abc import Callable
from pathlib import Path

from tamedpuma.app.compose import hydra_error_line, one_line
from tamedpuma.errors import TamedPumaError
from tamedpuma.paths import writable_problem


def fail(message: str, status: int = 2) -> None:
    """Print ``error: message`` (one line) on stderr and exit with ``status``."""
    print(f"error: {' '.join(message.split())}", file=sys.stderr)
    sys.exit(status)


def command(doc: str) -> Callable[[Callable[[list[str]], int]], Callable[..., int]]:
    """The frame of the entry points that are not Hydra mains (train, lasa, body_model): the
    decorated ``main(argv)`` gets the argument list (``sys.argv[1:]`` by default); ``-h`` or
    ``--help`` prints ``doc``; a :class:`TamedPumaError` becomes one line ``error: ...`` on
    stderr and status 2; Ctrl-C one line ``interrupted (Ctrl-C)`` and status 130 (no traceback).
    """
    def wrap(body: Callable[[list[str]], int]) -> Callable[..., int]:
        @functools.wraps(body)
        def main(argv: list[str] | None = None) -> int:
            argv = list(sys.argv[1:] if argv is None else argv)
            if argv and argv[0] in ("-h", "--help"):
                print(doc)
                return 0
            try:
                return body(argv)
            except TamedPumaError as exc:
                print(f"error: {' '.join(str(exc).split()) or type(exc).__name__}",
                      file=sys.stderr)
                return 2
            except KeyboardInterrupt:  # a command with a partial result says where it is first
                print("interrupted (Ctrl-C)", file=sys.stderr)
                return 130
        return main
    return wrap


# Hydra's command-line flags that take a value (the value is the next argument or after "=")
_VALUE_FLAGS = ("--config-dir", "-cd", "--config-path", "-cp", "--config-name", "-cn",
                "--package", "-p", "--experimental-rerun", "--shell-completion", "-sc")
#: Hydra's run modes, of which one command takes at most one
_MODES = {"-m": "--multirun", "--multirun": "--multirun", "-r": "--run", "--run": "--run",
          "-c": "--cfg", "--cfg": "--cfg", "-i": "--info", "--info": "--info",
          "-sc": "--shell-completion", "--shell-completion": "--shell-completion"}
_NO_CHECK = ("--help", "-h", "--hydra-help", "--info", "-i", "--cfg", "-c", "--resolve",
             "--shell-completion", "-sc", "--experimental-rerun")


_BASH_COMPLETION = """\
# bash completion of python -m {module}: eval "$(python -m {module} -sc install=bash)"
_{name}_completion()
{{
    local words=($COMP_LINE)
    if [[ "${{words[1]}}" != "-m" || "${{words[2]}}" != "{module}" ]]; then
        return 0
    fi
    local choices=$(COMP_POINT=$COMP_POINT COMP_LINE="$COMP_LINE" \\
        "${{words[0]}}" -m {module} -sc query=bash 2>/dev/null)
    COMPREPLY=($(compgen -o nospace -o default -W "$choices" -- "${{COMP_WORDS[COMP_CWORD]}}"))
}}
COMP_WORDBREAKS=${{COMP_WORDBREAKS//=}}
complete -o nospace -o default -F _{name}_completion python python3
"""
_SHELL_ACTIONS = ("install", "uninstall", "query")


def shell_completion(argv: list[str], module: str) -> list[str]:
    """Hydra's ``--shell-completion`` (``-sc``) for ``python -m module`` (Hydra's own scripts
    complete ``python script.py`` and installed programs only): ``install=bash`` prints a bash
    script for ``python -m module``; ``query=SHELL`` reads the line the shell passes
    (``COMP_LINE``) with ``python -m module`` as the program's name. Run as a console script
    (``tamedpuma-sweep``, ``sys.argv[0]`` not a ``.py`` file) Hydra's own completion serves,
    under the program's name. A bare flag or an unknown action is a one-line error.
    Returns ``argv`` for Hydra (unchanged without the flag); exits after printing a script."""
    _, _, flags = split_argv(argv)
    value = flags.get("--shell-completion", flags.get("-sc"))
    if value is None:
        return argv
    action, _, shell = value.partition("=")
    if action not in _SHELL_ACTIONS or not shell:
        fail(f"--shell-completion needs one of install=SHELL, uninstall=SHELL or query=SHELL "
             f"(SHELL: bash, zsh or fish), e.g. eval \"$(python -m {module} -sc install=bash)\"")
    if not sys.argv[0].endswith(".py"):  # a console script: Hydra's own completion names it
        return argv
    if action == "install" and shell == "bash":
        print(_BASH_COMPLETION.format(module=module, name=module.replace(".", "_")))
        sys.exit(0)
    if action == "query":
        import os

        line = os.environ.get("COMP_LINE", "")
        head = re.match(rf"^\s*\S*python[0-9.]*\s+-m\s+{re.escape(module)}(\s|$)", line)
        if head:  # the program's name as one word, as Hydra expects it
            os.environ["COMP_LINE"] = module + line[head.end() - len(head.group(1)):]
    return argv


def split_argv(argv: list[str]) -> tuple[list[str], list[str], dict[str, str]]:
    """Hydra's command line → (overrides, extra config search paths, flags with their values).

    ``--config-dir DIR`` / ``--config-dir=DIR`` / ``-cd DIR`` become the search path entry
    ``file://DIR`` (absolute); ``hydra.searchpath=[...]`` overrides stay among the overrides.
    Other flags (``-m``, ``--config-name X``...) are returned in the dict, not as overrides.
    """
    overrides, search, flags = [], [], {}
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg.startswith("-"):
            name, eq, value = arg.partition("=")
            if name in _VALUE_FLAGS and not eq and i + 1 < len(argv):
                value, i = argv[i + 1], i + 1
            flags[name] = value
            if name in ("--config-dir", "-cd") and value:
                search.append("file://" + str(Path(value).expanduser().resolve()))
        else:
            overrides.append(arg)
        i += 1
    return overrides, search, flags


def with_search_path(overrides: list[str], search: list[str]) -> list[str]:
    """``overrides`` with ``search`` entries put first into (or as) a ``hydra.searchpath``."""
    if not search:
        return list(overrides)
    from hydra.core.override_parser.overrides_parser import OverridesParser

    out, existing = [], []
    for arg in overrides:
        key = arg.split("=", 1)[0].lstrip("+~")
        if key == "hydra.searchpath":
            value = OverridesParser.create().parse_override(arg).value()
            existing.extend(value if isinstance(value, list) else [value])
        else:
            out.append(arg)
    entries = ",".join(f"'{p}'" for p in dict.fromkeys([*search, *existing]))
    return [f"hydra.searchpath=[{entries}]", *out]


def with_plugin_configs(argv: list[str]) -> list[str]:
    """``argv`` with the installed method plugins' config folders
    (:func:`tamedpuma.methods.config_dirs`) in its ``hydra.searchpath`` (merged with one the
    user gave), so ``method=<plugin>`` composes like a built-in method; unchanged without
    plugins (or with a malformed search path, which the pre-check reports)."""
    from tamedpuma.methods import config_dirs

    dirs = [f"file://{d.resolve()}" for d in config_dirs()]
    if not dirs:
        return list(argv)
    try:
        merged = with_search_path(list(argv), dirs)
    except Exception:  # noqa: BLE001 - a malformed override: precheck_overrides names it
        return list(argv)
    rest = merged[1:]
    at = _first_override(rest)  # Hydra's parser takes its overrides as one run of positionals
    return [*rest[:at], merged[0], *rest[at:]]


def _first_override(argv: list[str]) -> int:
    """Index of the first override (``key=value``) in ``argv``, skipping flags and their values
    (``-m``, ``--cfg job``, ``--config-name X``), or len(argv)."""
    skip = False
    for i, arg in enumerate(argv):
        if skip:
            skip = False
            continue
        if arg.startswith("-"):
            skip = "=" not in arg and arg in (*_VALUE_FLAGS, "--cfg", "-c")
            continue
        if "=" in arg or arg.startswith("~"):
            return i
    return len(argv)


def _schema_problem(config_name: str, cfg) -> str | None:
    """Types, unknown keys and ranges of a composed config (:mod:`tamedpuma.app.schema`)."""
    from tamedpuma.app import schema
    from tamedpuma.errors import ConfigError

    check = schema.CONFIGS.get(config_name)
    if check is None:
        return None
    try:
        check(cfg)
    except ConfigError as exc:
        return str(exc)
    return None


def _single_run_sweep(config_name: str, base: list[str], swept: list[str]) -> str | None:
    """The problem of sweep overrides (``swept``: ``a=1,2``, ``range(..)``, ``glob(..)``) in a
    single run: Hydra runs them only in multirun mode, which ``-m`` sets or the config
    (``hydra.mode``, as ``+experiment=table1`` sets it); None where the config sets it."""
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from tamedpuma.app.compose import compose

    try:
        mode = OmegaConf.select(compose(config_name, base, hydra_config=True), "hydra.mode")
    except Exception:  # the composition's own error is reported by the check that follows
        return None
    if mode == RunMode.MULTIRUN:
        return None
    return (f"{swept[0]!r} sweeps several values, which needs a multirun: add -m "
            f"(python -m tamedpuma.sweep -m {' '.join(swept)} ...)")


def _variants(parsed, search) -> tuple[list[str], list[list[str]]]:
    """The overrides with each listed sweep at its first value (the base), and the variants
    that take each sweep's other values one at a time (range and interval sweeps are left to
    Hydra)."""
    base, sweeps = with_search_path([ov.input_line for ov in parsed
                                     if ov.key_or_group == "hydra.searchpath"], search), []
    for ov in parsed:
        if ov.key_or_group.startswith("hydra"):
            continue
        if ov.is_sweep_override():
            try:
                values = list(ov.sweep_string_iterator())
            except Exception:  # range/interval sweeps: leave them to Hydra
                continue
            sweeps.append((ov, values))
            base.append(f"{ov.get_key_element()}={values[0]}")
        else:
            base.append(ov.input_line)
    variants = [base]
    for ov, values in sweeps:
        key = ov.get_key_element()
        for value in values[1:]:
            variants.append([a for a in base if not a.startswith(f"{key}=")] + [f"{key}={value}"])
    return base, variants


def precheck_overrides(config_name: str, argv: list[str]) -> str | None:
    """Compose ``config_name`` with the command line's overrides; the first problem, or None."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    from tamedpuma.app.compose import compose, session

    modes = {_MODES[a.split("=", 1)[0]] for a in argv if a.split("=", 1)[0] in _MODES}
    if len(modes) > 1:
        return ("use one of " + ", ".join(sorted(set(_MODES.values()))) + " at a time (got "
                + " and ".join(sorted(modes)) + ")")
    if any(a.split("=", 1)[0] in _NO_CHECK for a in argv):
        return None
    args, search, flags = split_argv(argv)
    for name in ("--config-dir", "-cd"):
        if name in flags and not Path(flags[name]).expanduser().is_dir():
            return f"config folder not found: {flags[name]!r} ({name})"
    config_name = flags.get("--config-name") or flags.get("-cn") or config_name
    try:
        parsed = OverridesParser.create().parse_overrides(args)
    except Exception as exc:  # Hydra's OverrideParseException and friends
        return f"malformed override: {one_line(exc)}"
    base, variants = _variants(parsed, search)
    swept = [ov.input_line for ov in parsed
             if ov.is_sweep_override() and not ov.key_or_group.startswith("hydra")]
    with session():
        if swept and "--multirun" not in modes:  # (with the command line's hydra.* settings)
            hydra_lines = [ov.input_line for ov in parsed if ov.key_or_group.startswith("hydra.")
                           and ov.key_or_group != "hydra.searchpath"
                           and not ov.is_sweep_override()]
            problem = _single_run_sweep(config_name, base + hydra_lines, swept)
            if problem:
                return problem
        for overrides in variants:
            try:
                cfg = compose(config_name, overrides)
                OmegaConf.to_container(cfg, resolve=True)
            except Exception as exc:  # composition and interpolation errors
                return hydra_error_line(exc, search)
            problem = _schema_problem(config_name, cfg)
            if problem:
                return problem
            if "output_root" in cfg:
                problem = writable_problem(str(cfg.output_root))
                if problem:
                    return problem
    return None

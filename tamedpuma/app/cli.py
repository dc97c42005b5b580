"""Shared by the Hydra entry points (sweep, train): one-line errors and an override pre-check.

Hydra reports a bad override over several lines with a hint about HYDRA_FULL_ERROR. Before Hydra
runs, :func:`precheck_overrides` composes the config once per value of every sweep list and turns
the first problem into one line; it also checks that ``output_root`` can be written.
"""

from __future__ import annotations

import sys
import uuid
from pathlib import Path

from tamedpuma.app.config import CONF_DIR


def fail(message: str, status: int = 2) -> None:
    """Print ``error: message`` (one line) on stderr and exit with ``status``."""
    print(f"error: {' '.join(message.split())}", file=sys.stderr)
    sys.exit(status)


_NOISE = ("full_key:", "object_type", "reference_type", "Config search path",
          "Set the environment variable HYDRA_FULL_ERROR")


def _one_line(exc: BaseException) -> str:
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


def _check_writable(root: str) -> str | None:
    path = Path(root)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".write-test-{uuid.uuid4().hex}"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        return f"output folder {root!r} is not writable: {exc.strerror or exc}"
    return None


def precheck_overrides(config_name: str, argv: list[str]) -> str | None:
    """Compose ``config_name`` with the command line's overrides; the first problem, or None."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    args = [a for a in argv if not a.startswith("-")]
    if any(a in ("--help", "-h", "--hydra-help", "--info", "--cfg", "-c") for a in argv):
        return None
    try:
        parsed = OverridesParser.create().parse_overrides(args)
    except Exception as exc:  # Hydra's OverrideParseException and friends
        return f"malformed override: {_one_line(exc)}"
    base, sweeps = [], []
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
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
            for overrides in variants:
                try:
                    cfg = compose(config_name, overrides=overrides)
                    OmegaConf.to_container(cfg, resolve=True)
                except Exception as exc:  # composition and interpolation errors
                    return _one_line(exc)
                if "output_root" in cfg:
                    problem = _check_writable(str(cfg.output_root))
                    if problem:
                        return problem
    finally:
        GlobalHydra.instance().clear()
    return None

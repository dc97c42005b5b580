"""The console scripts of pyproject.toml: one per ``python -m tamedpuma.<tool>`` entry point and
analysis, each naming a callable ``main``; run under its own name, the sweep's shell completion
is Hydra's, and tab completion of ``method=`` lists the methods."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python ≥ 3.11

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "tamedpuma"
SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
METHODS = sorted(p.stem for p in (PKG / "conf" / "method").glob("*.yaml"))


def _entry_modules() -> set[str]:
    """The modules run as ``python -m``: the package's shims and its analyses."""
    shims = {f"tamedpuma.{p.stem}" for p in PKG.glob("*.py")
             if p.stem != "__init__" and 'if __name__ == "__main__"' in p.read_text()}
    analyses = {f"tamedpuma.analysis.{p.stem}" for p in (PKG / "analysis").glob("*.py")
                if 'if __name__ == "__main__"' in p.read_text()}
    return shims | analyses


def test_every_entry_point_has_a_console_script():
    targets = {value.partition(":")[0] for value in SCRIPTS.values()}
    assert targets == _entry_modules()
    assert all(name.startswith("tamedpuma-") for name in SCRIPTS)


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_each_console_script_names_a_callable(name):
    module, _, attr = SCRIPTS[name].partition(":")
    assert callable(getattr(importlib.import_module(module), attr))


@pytest.fixture(scope="module")
def sweep_program(tmp_path_factory) -> dict:
    """A ``tamedpuma-sweep`` program on PATH, as pip writes a console script (its argv[0] is
    the program, not a .py file), running this checkout; the environment to call it with."""
    bin_dir = tmp_path_factory.mktemp("bin")
    program = bin_dir / "tamedpuma-sweep"
    module, _, attr = SCRIPTS["tamedpuma-sweep"].partition(":")
    program.write_text(f"#!{sys.executable}\nimport sys\nfrom {module} import {attr}\n"
                       f"sys.exit({attr}())\n")
    program.chmod(0o755)
    return {**os.environ, "PYTHONPATH": str(ROOT),
            "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}"}


def test_the_sweep_completion_query_lists_the_methods(sweep_program):
    line = "tamedpuma-sweep method="
    proc = subprocess.run(["tamedpuma-sweep", "-sc", "query=bash"], capture_output=True,
                          text=True, timeout=120,
                          env={**sweep_program, "COMP_LINE": line, "COMP_POINT": str(len(line))})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == [f"method={m}" for m in METHODS]


@pytest.mark.skipif(not Path("/bin/bash").exists(), reason="no bash")
def test_the_installed_bash_completion_completes_method_names(sweep_program):
    script = subprocess.run(["tamedpuma-sweep", "-sc", "install=bash"], capture_output=True,
                            text=True, timeout=120, env=sweep_program).stdout
    assert "-F hydra_bash_completion tamedpuma-sweep" in script
    test = (script + '\nCOMP_LINE="tamedpuma-sweep method=f"; COMP_POINT=${#COMP_LINE}\n'
            "COMP_WORDS=(tamedpuma-sweep method=f); COMP_CWORD=1\n"
            'hydra_bash_completion; printf "%s\\n" "${COMPREPLY[@]}"\n')
    proc = subprocess.run(["/bin/bash", "-c", test], env=sweep_program, capture_output=True,
                          text=True, timeout=120)
    assert proc.stdout.split() == [f"method={m}" for m in METHODS if m.startswith("f")], (
        proc.stderr[-2000:])

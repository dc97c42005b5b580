"""The dependency rules of the layout (docs/extending.md, "Layout and data flow"), enforced on
the source with ast."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "tamedpuma"


def _imports(path: Path, text: str | None = None) -> set[str]:
    """Every module a file imports (at the top or inside functions), absolute; with ``from M
    import a`` both ``M`` and ``M.a`` (a may be a module)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text() if text is None else text)):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                module = node.module
            else:
                base = ".".join(path.relative_to(PKG.parent).with_suffix("").parts[:-node.level])
                module = f"{base}.{node.module}" if node.module else base
            names.add(module)
            # `from tamedpuma import episode`, `from . import fpm`: the names may be modules
            names |= {f"{module}.{a.name}" for a in node.names if a.name != "*"}
    return names


def _modules():
    return sorted(p for p in PKG.rglob("*.py"))


def _top(names):
    return {n.split(".")[0] for n in names}


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PKG)))
def test_import_rules(path):
    rel = path.relative_to(PKG)
    names = _imports(path)
    top = _top(names)
    if "pybullet" in top:  # (and the reference planner's own script, which the reference's
        # interpreter runs apart from the package, its episode in a PyBullet world of its own)
        assert rel.as_posix() in ("worlds/bullet.py", "app/reference_fabrics.py"), \
            "only the simulator imports PyBullet"
    if "hydra" in top:
        assert rel.parts[0] == "app", "only entry points (app/) import Hydra"
    if "torch" in top:
        assert rel.parts[0] in ("puma", "app"), "torch only in the learner and entry points"
    if rel.parts[0] == "methods":
        assert "tamedpuma.worlds.bullet" not in names, "methods never import the simulator"
    if rel.parts[0] == "fabrics" or rel.as_posix() in (
            "types.py", "robot/rotations.py", "metrics.py", "methods/_modulation.py",
            "methods/_policy.py"):
        allowed = {"numpy", "tamedpuma", "__future__", "collections", "dataclasses", "typing",
                   "math", "warnings"}
        if rel.as_posix() == "fabrics/compiled.py":  # the optional compiled kernels
            allowed |= {"numba", "importlib", "types"}
        assert top <= allowed, f"{rel} must stay numpy-only: {top}"


#: Hydra's compose API and its global state: only app/compose.py uses them (the sweep's own
#: ``@hydra.main`` initializes Hydra itself)
COMPOSE_API = {"compose", "initialize", "initialize_config_dir", "initialize_config_module"}
COMPOSER = "app/compose.py"


def _compose_api_uses(path: Path, text: str | None = None) -> set[str]:
    """The uses of Hydra's compose/initialize API and of its global state in a file: imports
    (``from hydra import compose``, ``import hydra.core.global_hydra``) and attributes of an
    imported ``hydra`` (``hydra.compose(...)``)."""
    names = {n for n in _imports(path, text)
             if n in {f"hydra.{a}" for a in COMPOSE_API} or n.startswith("hydra.core.global_hydra")}
    for node in ast.walk(ast.parse(path.read_text() if text is None else text)):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id == "hydra" and node.attr in COMPOSE_API:
            names.add(f"hydra.{node.attr}")
    return names


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PKG)))
def test_only_one_module_composes_the_config(path):
    rel = path.relative_to(PKG).as_posix()
    uses = _compose_api_uses(path)
    if rel == COMPOSER:
        assert "hydra.compose" in uses and "hydra.initialize_config_dir" in uses
    else:
        assert not uses, f"{rel} uses {sorted(uses)}: compose through tamedpuma.app.compose"


def test_the_compose_scan_sees_every_form():
    source = ("import hydra\nfrom hydra import compose as c\n"
              "def f():\n    from hydra.core.global_hydra import GlobalHydra\n"
              "    hydra.initialize(config_path='x')\n    return hydra.main\n")
    assert _compose_api_uses(PKG / "app" / "sweep.py", source) == {
        "hydra.compose", "hydra.core.global_hydra", "hydra.core.global_hydra.GlobalHydra",
        "hydra.initialize"}
    assert _compose_api_uses(PKG / "app" / "sweep.py", "import hydra\nhydra.main()\n") == set()


def _reads_config_yaml(path: Path, text: str | None = None) -> list[str]:
    """Where a file reaches the config files itself: the config folder (``CONF_DIR``) or a YAML
    file loaded by OmegaConf (``OmegaConf.load``)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text() if text is None else text)):
        if isinstance(node, ast.Name) and node.id == "CONF_DIR" \
                or isinstance(node, ast.alias) and node.name == "CONF_DIR":
            found.append(f"CONF_DIR (line {getattr(node, 'lineno', '?')})")
        elif isinstance(node, ast.Attribute) and node.attr == "load" \
                and isinstance(node.value, ast.Name) and node.value.id == "OmegaConf":
            found.append(f"OmegaConf.load (line {node.lineno})")
    return found


@pytest.mark.parametrize("path", [p for p in _modules() if p.relative_to(PKG).parts[0] != "app"
                                  and p.relative_to(PKG).as_posix() != "paths.py"],
                         ids=lambda p: str(p.relative_to(PKG)))
def test_only_the_entry_points_read_config_files(path):
    """Below the entry points (``app/``) modules receive config values; none reads a config
    YAML (``paths.py`` only names the folder)."""
    found = _reads_config_yaml(path)
    assert not found, f"{path.relative_to(PKG)} reads config files itself: {found}; pass the " \
        "values down"


def test_the_config_read_scan_sees_every_form():
    source = ("from tamedpuma.paths import CONF_DIR\nfrom omegaconf import OmegaConf\n"
              "def f():\n    return OmegaConf.load(CONF_DIR / 'x.yaml')\n")
    assert len(_reads_config_yaml(PKG / "worlds" / "scenarios.py", source)) == 3
    assert _reads_config_yaml(PKG / "worlds" / "scenarios.py",
                              "import yaml\nyaml.safe_load(log_text)\n") == []


#: the layers, lowest first: a module imports only from its own package or lower layers
LAYERS = [{"errors", "startup", "termination", "parallel", "jit"},
          {"types", "records", "paths", "runlog"}, {"robot"},
          {"fabrics", "puma", "ik_solvers"},
          {"methods", "worlds"}, {"metrics"}, {"episode"}, {"recording"}, {"analysis"},
          {"app"}]
_SHIMS = {"sweep", "train", "lasa", "bench_fabrics", "bench", "replay", "body_model", "models",
          "safety_suite", "ablation", "recheck", "__init__", "__main__"}


def _layer(part: str) -> int:
    for i, names in enumerate(LAYERS):
        if part in names:
            return i
    if part in _SHIMS:
        return len(LAYERS)  # thin entry-point shims: above everything
    raise AssertionError(f"tamedpuma/{part} has no layer: add it to LAYERS")


def _package(path: Path) -> str:
    rel = path.relative_to(PKG)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _upward(path: Path, names: set[str]) -> list[str]:
    """The imports in ``names`` of the module at ``path`` that are not of a lower layer."""
    own = _package(path)
    bad = []
    for name in names:
        parts = name.split(".")
        if parts[0] != "tamedpuma" or len(parts) < 2 or parts[1] == own:
            continue
        if not _layer(parts[1]) < _layer(own):
            bad.append(name)
    return bad


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PKG)))
def test_layers_import_only_downwards(path):
    bad = _upward(path, _imports(path))
    assert not bad, f"{path.relative_to(PKG)} ({_package(path)}) imports {bad}: not a lower layer"


def test_the_layer_rule_flags_upward_and_sideways_imports():
    kin, scen = PKG / "robot" / "kinematics.py", PKG / "worlds" / "scenarios.py"
    assert _upward(kin, {"tamedpuma.methods.fpm"}) == ["tamedpuma.methods.fpm"]  # upward
    assert _upward(scen, {"tamedpuma.methods"}) == ["tamedpuma.methods"]  # same layer, sideways
    assert _upward(scen, {"tamedpuma.robot.kinematics", "tamedpuma.worlds.bullet", "numpy"}) == []


@pytest.mark.parametrize("path", sorted((PKG / "methods").glob("*.py")), ids=lambda p: p.name)
def test_methods_never_import_each_other(path):
    for name in _imports(path):
        parts = name.split(".")
        if parts[:2] == ["tamedpuma", "methods"] and len(parts) > 2:
            assert parts[2].startswith("_"), \
                f"methods/{path.name} imports {name}: share it through a private module"


def test_the_import_scan_sees_every_form():
    """The scan these rules rest on: plain, from-package, relative and function-local imports."""
    source = ("import tamedpuma.types\nfrom tamedpuma import episode\nfrom . import fpm\n"
              "from ._tamed import Forcing\nfrom ..robot import rotations as r\n"
              "def f():\n    from tamedpuma.worlds import bullet\n")
    names = _imports(PKG / "methods" / "cpm.py", source)
    assert {"tamedpuma.types", "tamedpuma.episode", "tamedpuma.methods.fpm",
            "tamedpuma.methods._tamed", "tamedpuma.robot.rotations",
            "tamedpuma.worlds.bullet"} <= names


#: the control loop (episode and its metrics, the methods' steps), the fabric assembly and the
#: training loop, like every other module of the package: no function over 60 lines
LOOPS = ["episode.py", "metrics.py", "puma/training.py", "puma/losses.py",
         *(p.relative_to(PKG).as_posix() for p in (PKG / "fabrics").glob("*.py")),
         *(p.relative_to(PKG).as_posix() for p in (PKG / "methods").glob("*.py"))]
SHORT = sorted(p.relative_to(PKG).as_posix() for p in _modules())


def test_the_loops_are_held_to_the_rule():
    assert set(LOOPS) <= set(SHORT) and len(LOOPS) > 15


@pytest.mark.parametrize("rel", SHORT)
def test_no_long_function(rel):
    tree = ast.parse((PKG / rel).read_text())
    long = [f"{n.name}: {n.end_lineno - n.lineno + 1} lines" for n in ast.walk(tree)
            if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
            and n.end_lineno - n.lineno + 1 > 60]
    assert not long, f"{rel}: {long}"


#: where rotations are computed: numpy (robot/rotations.py) and PUMA's differentiable torch maps
ROTATION_MODULES = {"robot/rotations.py", "puma/manifold.py"}


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PKG)))
def test_rotation_helpers_live_in_the_rotation_modules(path):
    """No module-level quaternion / rotation function outside robot/rotations.py (and PUMA's
    torch manifold): a new one belongs there."""
    if path.relative_to(PKG).as_posix() in ROTATION_MODULES:
        return
    tree = ast.parse(path.read_text())
    helpers = [n.name for n in tree.body if isinstance(n, ast.FunctionDef)
               and any(w in n.name for w in ("quat", "rotation", "rpy", "so3", "skew", "euler"))]
    assert not helpers, f"{path.relative_to(PKG)} defines {helpers}: move to robot/rotations.py"


"""``python -m tamedpuma.app.config_page``: write ``docs/configuration.md`` from the schema.

Every key of the three entry points' configs (``tamedpuma.sweep``, ``tamedpuma.train``,
``tamedpuma.body_model``) and of every method, read from :mod:`tamedpuma.app.schema`: its type
(the dataclass annotation), its default (the value the shipped YAML gives it in the default
composition, with the schema's own default beside it where the two differ), its valid range (the
rule of the schema's or the library dataclass's check, as its error message states it) and its
meaning (the field's comment in the source, else its paragraph in the class docstring). The page
is generated, never edited: ``tests/test_docs.py`` fails when it differs from what this module
writes, so a new key or a changed default shows up in the documentation with the change itself.

    python -m tamedpuma.app.config_page            # rewrite docs/configuration.md
    python -m tamedpuma.app.config_page --check    # status 1 if the page is stale
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import io
import re
import sys
import textwrap
import tokenize
import typing
from pathlib import Path

from omegaconf import MISSING, OmegaConf

from tamedpuma.app import schema
from tamedpuma.app.compose import compose
from tamedpuma.app.config import options_in
from tamedpuma.paths import CONF_DIR, project_root

#: the page, in :func:`tamedpuma.paths.project_root`: the checkout's, else (an installed
#: package) docs/ of the current folder
PAGE = Path("docs") / "configuration.md"
RULE_CALLS = {"positive": "a finite number > 0", "nonneg": "a finite number >= 0"}
MUST = re.compile(r"^([\w.\[\]{}* /]+?) must be (.+?)(?:[,;] got\b.*)?$", re.S)


# ----------------------------------------------------------------------------- source reading


def _sources(cls: type) -> list[type]:
    """``cls`` and the classes its fields come from: its bases and, for a schema class made by
    ``schema._with_fields_of``, the library dataclass (found in its ``__post_init__`` closure)."""
    found = [c for c in cls.__mro__ if dataclasses.is_dataclass(c)]
    hook = getattr(cls, "__post_init__", None)
    for cell in getattr(hook, "__closure__", None) or ():
        value = cell.cell_contents
        if isinstance(value, type) and dataclasses.is_dataclass(value):
            found += [c for c in value.__mro__ if dataclasses.is_dataclass(c)]
    return list(dict.fromkeys(found))


@functools.cache
def _source(cls: type) -> str:
    try:
        return textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):  # made at run time (schema._with_fields_of): no source
        return ""


@functools.cache
def _comments(cls: type) -> dict[str, str]:
    """Field name -> its comment: the comment on the field's line and the comment-only lines
    right below it."""
    text = _source(cls)
    if not text:
        return {}
    lines = text.splitlines()
    notes = {tok.start[0]: tok.string.lstrip("#").strip()
             for tok in tokenize.generate_tokens(io.StringIO(text).readline)
             if tok.type == tokenize.COMMENT}
    field_line = re.compile(r"^    (\w+)\s*:\s*[^=]")
    out: dict[str, str] = {}
    for number, line in enumerate(lines, start=1):
        match = field_line.match(line)
        if not match or number not in notes:
            continue
        parts = [notes[number]]
        below = number + 1
        while below in notes and lines[below - 1].lstrip().startswith("#"):
            parts.append(notes[below])
            below += 1
        out[match.group(1)] = " ".join(p for p in parts if p)
    return out


def _from_docstring(cls: type, name: str) -> str:
    """The clause of ``cls``'s docstring that starts with ``name`` (``name ...: meaning;``)."""
    doc = " ".join((inspect.getdoc(cls) or "").split())
    pattern = rf"(?:^|[\s;(*`])``?{re.escape(name)}``?(?:\s[^:;.]{{0,40}})?:\s+(.+?)(?:;\s|\.\s|$)"
    match = re.search(pattern, doc)
    return match.group(1).strip() if match else ""


def meaning(cls: type, name: str, key: str = "", notes: dict | None = None) -> str:
    """The field's comment or docstring clause in the source, else its comment in the YAML."""
    for source in _sources(cls):
        note = _comments(source).get(name) or _from_docstring(source, name)
        if note:
            return note
    return (notes or {}).get(key, "")


@functools.cache
def yaml_notes(path: Path, root: str) -> dict[str, str]:
    """Dotted key (under ``root``) -> the comment on its line in a YAML file, with the
    comment-only lines below it that start in the same column (a wrapped comment)."""
    lines = path.read_text().splitlines()
    entry = re.compile(r"^(\s*)([\w-]+):[^#]*?(#\s*(.*))?$")
    out: dict[str, str] = {}
    stack: list[tuple[int, str]] = []
    for i, line in enumerate(lines):
        match = entry.match(line)
        if not match:
            continue
        indent = len(match.group(1))
        stack = [(d, k) for d, k in stack if d < indent] + [(indent, match.group(2))]
        if not match.group(3):
            continue
        column, parts = line.index("#"), [match.group(4).strip()]
        for below in lines[i + 1:]:
            if not below.strip().startswith("#") or below.index("#") != column:
                break
            parts.append(below.strip().lstrip("#").strip())
        key = ".".join([root] * bool(root) + [k for _, k in stack])
        out.setdefault(key, " ".join(p for p in parts if p))
    return out


def group_notes(group: str, first: str, root: str | None = None) -> dict[str, str]:
    """YAML comments of a config group's files, its default option ``first`` taking precedence."""
    folder = CONF_DIR / group
    files = sorted(folder.rglob("*.yaml"), key=lambda p: (p.stem != first, str(p)))
    notes: dict[str, str] = {}
    for path in files:
        for key, note in yaml_notes(path, group if root is None else root).items():
            notes.setdefault(key, note)
    return notes


# ----------------------------------------------------------------------------- ranges


def _evaluate(node: ast.AST, names: dict) -> object:
    return eval(compile(ast.Expression(node), "<schema>", "eval"), names)  # noqa: S307


def _template(node: ast.AST) -> str | None:
    """A message's text with every ``{...}`` part as ``{}`` (None if not a string)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value if isinstance(v, ast.Constant) else "{}" for v in node.values)
    return None


def _loop_names(loop: ast.For, function: ast.AST, names: dict) -> list[str]:
    """The string values a ``for name in ...`` loop runs over (a tuple, or a name bound to one)."""
    try:
        return [str(v) for v in _evaluate(loop.iter, names)]
    except Exception:  # a name bound inside the function
        pass
    for node in ast.walk(function):
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == getattr(loop.iter, "id", None)
                for t in node.targets):
            try:
                return [str(v) for v in _evaluate(node.value, names)]
            except Exception:
                return []
    return []


def _call_rules(call: ast.Call, names: dict) -> list[tuple[str, str]]:
    """(key, rule) of one ``check(ok, key, rule, value)``, ``positive(key, v)`` or
    ``nonneg(key, v)`` call (``_check`` etc. in the schema) of a settings class."""
    func = getattr(call.func, "id", "").lstrip("_")
    try:
        if func == "check" and len(call.args) >= 3:
            return [(str(_evaluate(call.args[1], names)), str(_evaluate(call.args[2], names)))]
        if func in RULE_CALLS and call.args:
            return [(str(_evaluate(call.args[0], names)), RULE_CALLS[func])]
    except Exception:  # a key built from a loop variable: left to the message rule
        pass
    return []


def _message_rules(node: ast.AST, loops: list[list[str]]) -> list[tuple[str, str]]:
    """(key, rule) of an error message ``"<key> must be <rule>, got ..."``; a ``{}`` in the key
    stands for each value of the innermost enclosing loop."""
    text = _template(node)
    match = MUST.match(" ".join(text.split())) if text else None
    if not match:
        return []
    key, rule = match.group(1), match.group(2).replace("{}", "…").strip()
    if "{}" in key:
        return [(key.replace("{}", name), rule) for name in (loops[-1] if loops else [])]
    return [(key, rule)]


@functools.cache
def rules(cls: type) -> dict[str, str]:
    """Every range rule found in ``cls``'s source: key (as the message names it) -> rule."""
    text = _source(cls)
    if not text:
        return {}
    names = vars(sys.modules[cls.__module__])
    found: dict[str, str] = {}

    def visit(node: ast.AST, function: ast.AST, loops: list[list[str]]) -> None:
        if isinstance(node, ast.FunctionDef):
            function = node
        if isinstance(node, ast.For):
            loops = loops + [_loop_names(node, function, names)]
        if isinstance(node, ast.Call):
            for key, rule in _call_rules(node, names):
                found.setdefault(key, rule)
        for key, rule in _message_rules(node, loops):
            found.setdefault(key, rule)
        for child in ast.iter_child_nodes(node):
            visit(child, function, loops)

    tree = ast.parse(text)
    visit(tree, tree, [])
    return found


def valid_range(cls: type, key: str, name: str) -> str:
    """The rule for ``key`` (the full dotted key) or, failing that, for the field ``name`` of
    ``cls`` as any of its source classes' messages names it."""
    for source in _sources(cls):
        found = rules(source)
        if key in found:
            return found[key]
        for named, rule in found.items():
            if re.fullmatch(rf"(?:.*[.\s])?{re.escape(name)}(?:\s.*)?", named):
                return rule
    return ""


# ----------------------------------------------------------------------------- rows


def type_name(hint) -> str:
    """An annotation as it reads in the source: ``list[float]``, ``str | None``, a class name."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is typing.Any:
        return "any"
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " | ".join(type_name(a) for a in args)
    if origin is not None:
        inner = ", ".join("..." if a is Ellipsis else type_name(a) for a in args)
        return f"{getattr(origin, '__name__', str(origin))}[{inner}]"
    if hint is type(None):
        return "None"
    return getattr(hint, "__name__", str(hint))


def _nested(hint) -> tuple[type | None, bool]:
    """The dataclass a field holds (None if it holds none) and whether it holds a list of them."""
    for arg in (hint, *typing.get_args(hint)):
        if isinstance(arg, type) and dataclasses.is_dataclass(arg):
            return arg, False
        if typing.get_origin(arg) is list:
            inner = typing.get_args(arg)
            if inner and isinstance(inner[0], type) and dataclasses.is_dataclass(inner[0]):
                return inner[0], True
    return None, False


def _schema_default(f: dataclasses.Field, parent=None):
    if parent is not None:  # a field of a dataclass instance that is itself a default
        value = getattr(parent, f.name)
    elif f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return MISSING
    if dataclasses.is_dataclass(value):
        return None
    return list(value) if isinstance(value, tuple) else value


def show(value) -> str:
    if value is MISSING or value == "???":
        return "required"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, dict) and not value:
        return "{}"
    if isinstance(value, float) and value in (float("inf"), float("-inf")):
        return "inf" if value > 0 else "-inf"
    if isinstance(value, list) and len(value) > 8:
        return f"{len(value)} values"
    return "null" if value is None else str(value).replace("'", "")


def rows(cls: type, prefix: str, composed, skip: tuple[str, ...] = (),
         notes: dict | None = None, parent=None) -> list[list[str]]:
    """One row per key of ``cls`` under ``prefix``: key, type, default, range, meaning
    (``parent``: the default instance of ``cls`` where its field's default is one)."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if f.name in skip or f.name.startswith("_"):
            continue
        key = f"{prefix}.{f.name}" if prefix else f.name
        nested, many = _nested(hints[f.name])
        if nested is not None:
            inner = f"{key}[]" if many else key
            out.append([key, type_name(hints[f.name]), _default(f, key, composed, many, parent),
                        valid_range(cls, key, f.name), meaning(cls, f.name, key, notes)])
            if parent is not None:
                own = getattr(parent, f.name)
            elif f.default_factory is not dataclasses.MISSING:  # e.g. FPM's own Forcing()
                own = f.default_factory()
            else:
                own = f.default
            out += rows(nested, inner, None if many else composed, notes=notes,
                        parent=own if dataclasses.is_dataclass(own) else None)
            continue
        out.append([key, type_name(hints[f.name]), _default(f, key, composed, False, parent),
                    valid_range(cls, key, f.name), meaning(cls, f.name, key, notes)])
    return out


def _default(f: dataclasses.Field, key: str, composed, many: bool, parent=None) -> str:
    """The composed config's value, with the schema's beside it where they differ."""
    own = _schema_default(f, parent)
    if composed is None:
        return show(own) if own is not None or f.default is None else "—"
    value = OmegaConf.select(composed, key, default=MISSING, throw_on_missing=False)
    value = OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value
    if many and isinstance(value, list):
        return f"{len(value)} entries"
    if isinstance(value, dict):
        return show(value) if not value else "—"
    if value is MISSING or value == own or (own is None and dataclasses.is_dataclass(f.type)):
        return show(own if value is MISSING else value)
    return f"{show(value)} (schema: {show(own)})"


# ----------------------------------------------------------------------------- page


def table(title: str, intro: str, body: list[list[str]]) -> list[str]:
    def cell(text: str) -> str:
        return " ".join(str(text).split()).replace("|", "\\|") or "—"

    lines = [f"## {title}", "", intro, "", "| key | type | default | range | meaning |",
             "|---|---|---|---|---|"]
    lines += [f"| `{r[0]}` | `{cell(r[1])}` | {cell(r[2])} | {cell(r[3])} | {cell(r[4])} |"
              for r in body]
    return lines + [""]


HEAD = """# Configuration

Generated by `python -m tamedpuma.app.config_page` from `tamedpuma/app/schema.py`: do not edit by
hand (`tests/test_docs.py` fails when this page is stale). Every key is set on the command line as
`key=value` (`python -m tamedpuma.sweep scenario.max_steps=500`); a key the schema does not know,
a value of the wrong type or out of its range is refused before anything runs, with one line
naming the key and the rule (status 2).

*default* is the value a run gets with no override: the shipped YAML of the default option of each
group (`conf/sweep.yaml`: `robot=iiwa14 task=tomato scenario=default method=fpm recorder=default
sim=direct disturbance=none`; for each method, `method=<name>`), with the schema's own default
beside it where the YAML changes it. *range* is the rule the check states; an empty range means
any value of the type. *meaning* is the field's comment or docstring in the source.
"""


#: the default option of each run group (conf/sweep.yaml's defaults list)
DEFAULT_OPTIONS = {"robot": "iiwa14", "task": "tomato", "scenario": "default",
                   "recorder": "default", "sim": "direct", "disturbance": "none"}


def _run_groups() -> list[tuple[str, type]]:
    hints = typing.get_type_hints(schema.RunConfig)
    return [(f.name, _nested(hints[f.name])[0]) for f in dataclasses.fields(schema.RunConfig)
            if _nested(hints[f.name])[0] is not None]


def run_sections() -> list[str]:
    run = compose("sweep", [])
    notes = dict(yaml_notes(CONF_DIR / "sweep.yaml", ""))
    for group, first in DEFAULT_OPTIONS.items():
        notes.update(group_notes(group, first))
    groups = _run_groups()
    lines = table("Run: top level", "`python -m tamedpuma.sweep` (`conf/sweep.yaml`).",
                  rows(schema.RunConfig, "", run, ("method", *(g for g, _ in groups)), notes))
    for group, cls in groups:
        where = f"`conf/{group}/`" if (CONF_DIR / group).is_dir() else "`conf/sweep.yaml`"
        lines += table(f"Run: `{group}`", f"{where}; schema `{cls.__name__}`.",
                       rows(cls, group, run, notes=notes))
    return lines


def method_sections() -> list[str]:
    fabric = group_notes("fabric", "default", "method.fabric")
    lines = []
    for name, cls in schema.METHODS.items():
        if not (CONF_DIR / "method" / f"{name}.yaml").is_file():
            continue  # a method plugin's page is its own package's
        notes = {**yaml_notes(CONF_DIR / "method" / f"{name}.yaml", "method"), **fabric}
        composed = compose("sweep", [f"method={name}"])
        lines += table(f"Method `{name}`", f"`method={name}` (`conf/method/{name}.yaml`); "
                       f"schema `{cls.__name__}`.", rows(cls, "method", composed, notes=notes))
    return lines


def other_sections() -> list[str]:
    notes = {**yaml_notes(CONF_DIR / "train.yaml", ""), **group_notes("puma", "default")}
    lines = table("Training", "`python -m tamedpuma.train` (`conf/train.yaml`, `conf/puma/`); "
                  "its `task` group is the run's (above).",
                  rows(schema.TrainRunConfig, "", compose("train", []), ("task",), notes))
    notes = yaml_notes(CONF_DIR / "body_model.yaml", "")
    lines += table("Body model", "`python -m tamedpuma.body_model` (`conf/body_model.yaml`); "
                   "its `robot` group is the run's (above).",
                   rows(schema.BodyModelRunConfig, "", compose("body_model", []), ("robot",),
                        notes))
    return lines


#: what each config group sets (its options are read from conf/)
GROUPS = {
    "robot": "URDF, joints and their limits, end effector, home pose, elbow-up target, body "
             "spheres (the paper's check) and guard spheres (the controllers only)",
    "task": "goal pose, demonstrations, workspace (`from_demos`: all derived from the data)",
    "scenario": "start, obstacles, goal motion, Δt, step limit (`random`: generated from "
                "`scenario.random_seed`; `from_demos`: from the task's demonstrations)",
    "method": "the controller and its options (the sections below)",
    "fabric": "the fabric gains of `fabrics`, `fpm`, `cpm` (`fabric@method.fabric=reference`)",
    "recorder": "what is written per step (MCAP, Rerun, both, none)",
    "sim": "PyBullet window or not, substep, motor force, velocity or impedance control",
    "disturbance": "what perturbs the run (goal change, push, noisy sensing, impedance control)",
    "case": "a (task, scenario) pair, so one sweep covers both tasks (`+case=`)",
    "ablation": "FPM or CPM without one addition each (`+experiment=ablation`, docs/method.md)",
    "experiment": "a whole experiment's sweep (`+experiment=`, docs/experiments.md)",
    "puma": "the PUMA network and its training (`python -m tamedpuma.train`)",
    "hydra/launcher": "how a sweep's jobs run: `cores` (all cores: Hydra's joblib launcher whose "
                      "workers read each config file and compose each selection of groups once), "
                      "and the installed Hydra "
                      "launcher plugins' `submitit_slurm`, `submitit_local`, `ray`",
}


def collapsed(options: list[str]) -> str:
    """Options as a list, numbered runs shortened: `tomato/00` … `tomato/14`."""
    out, run = [], []

    def flush():
        if len(run) > 2:
            out.append(f"`{run[0]}` … `{run[-1]}`")
        else:
            out.extend(f"`{o}`" for o in run)
        run.clear()

    for option in options:
        match = re.fullmatch(r"(.*?)(\d+)", option)
        prev = re.fullmatch(r"(.*?)(\d+)", run[-1]) if run else None
        if match and prev and prev.group(1) == match.group(1) and (
                int(match.group(2)) == int(prev.group(2)) + 1):
            run.append(option)
            continue
        flush()
        if match:
            run.append(option)
        else:
            out.append(f"`{option}`")
    flush()
    return ", ".join(out)


def package_options(group: str) -> list[str]:
    """The options of ``group`` the package ships (the page is the same wherever it is
    generated; an installed method plugin documents its own)."""
    return options_in(CONF_DIR / group)


def group_section() -> list[str]:
    lines = ["## Config groups", "", "Choose an option with `group=option` (`python -m "
             "tamedpuma.sweep task=pouring method=cpm`); the keys each sets are below.", "",
             "| group | options | what it sets |", "|---|---|---|"]
    for group, what in GROUPS.items():
        lines.append(f"| `{group}` | {collapsed(package_options(group))} | {what} |")
    return lines + [""]


def sections() -> list[str]:
    return (HEAD.splitlines() + [""] + group_section() + run_sections() + method_sections()
            + other_sections())


def render() -> str:
    return "\n".join(sections()).rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="status 1 if the page is stale")
    parser.add_argument("--out", type=Path, default=None, help=f"default: {PAGE} of the "
                        "checkout (installed: of the current folder)")
    args = parser.parse_args(argv)
    args.out = args.out or project_root() / PAGE
    text = render()
    if args.check:
        current = args.out.read_text() if args.out.is_file() else ""
        stale = current != text
        print(f"{args.out}: " + ("stale: run python -m tamedpuma.app.config_page" if stale
                                  else "current"))
        return int(stale)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

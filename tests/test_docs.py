"""The documentation is short, current and runnable: README.md stays within 300 lines, every
command in it is run by a test or by ``.ci/run``, its links and the pages' links resolve,
``docs/configuration.md`` is what the schema generates, and the documentation and the files
listed below say what the project does without development history (no session or issue
numbers).

A *README command* is a line of a fenced ``bash`` block (backslash continuations joined, a
trailing ``# comment`` dropped). :data:`COVERED` says where each one runs: verbatim in
``.ci/run``, or in a named test, which runs the command (or its entry point with the same
arguments) with test-size overrides. A command added to the README without an entry here fails
:func:`test_every_readme_command_is_run_somewhere`.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
THIS = "tests/test_docs.py"

#: README command -> where it runs: ".ci/run" (verbatim) or "tests/<file>.py::<test>"
COVERED = {
    'pip install -e ".[dev]" && python -m tamedpuma.sweep': ".ci/run",
    "pytest -q": ".ci/run",
    "python -m tamedpuma.sweep method=cpm task=pouring":
        f"{THIS}::test_the_other_method_on_the_other_task_runs",
    "python -m tamedpuma.sweep +experiment=table1":
        "tests/test_table1_command.py::test_a_small_table1_sweep_runs_in_parallel_and_ends_with_"
        "the_table",
    "python -m tamedpuma.analysis.tables runs/table1":
        "tests/test_analysis.py::test_table1_is_rebuilt_from_the_logs_alone",
    "python -m tamedpuma.train task=from_demos task.demos=PATH task.name=my_motion":
        "tests/test_task_from_demos.py::test_training_from_a_csv_folder_writes_the_derivation",
    "python -m tamedpuma.sweep -m task=from_demos task.demos=PATH task.name=my_motion "
    "scenario=from_demos method=fpm,cpm seed=0,1,2":
        "tests/test_task_from_demos.py::test_a_new_task_runs_with_obstacles_at_once",
    "python -m tamedpuma.models list": f"{THIS}::test_the_models_list_names_every_task",
    # the viewer needs a display: the tests prepare and serve the same replay without one
    "python -m tamedpuma.replay runs/<run>":
        "tests/test_replay.py::test_replay_is_rebuilt_from_the_mcap_with_every_step",
    "python -m tamedpuma.replay runs/<run> --web":
        "tests/test_replay.py::test_web_serving_hands_the_files_to_the_viewer_with_cors",
    "python -m tamedpuma.replay runs/<run> --screenshot shot.png":
        "tests/test_replay.py::test_rendered_replay_shows_the_arm_where_its_links_project",
    "python -m tamedpuma.sweep -m method=puma,fpm,cpm scenario=tomato/00,tomato/03,tomato/07 "
    "without_obstacles=false,true recorder=mcap output_root=runs/look":
        f"{THIS}::test_the_look_at_a_run_commands_run_in_order",
    "python -m tamedpuma.analysis.figures runs/look --out docs/img --formats png":
        f"{THIS}::test_the_look_at_a_run_commands_run_in_order",
    "python -m tamedpuma.analysis.report runs/look":
        f"{THIS}::test_the_look_at_a_run_commands_run_in_order",
    # a SLURM cluster is not at hand: the launcher's config is composed from the command
    "python -m tamedpuma.sweep +experiment=table1 hydra/launcher=submitit_slurm "
    "hydra.launcher.partition=PARTITION hydra.launcher.timeout_min=30 "
    "hydra.launcher.cpus_per_task=1 hydra.launcher.mem_gb=4":
        f"{THIS}::test_the_slurm_command_composes_its_launcher",
    "python -m tamedpuma.sweep +experiment=table1 hydra/launcher=submitit_local":
        "tests/test_table1_command.py::test_the_same_sweep_through_submitit_local",
}

#: the fabric and analysis modules of this list (the others' owners are rewriting them)
#: the files that must not carry development history (session or issue numbers): every text
#: file of the checkout (git's list where there is one)
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".json", ".cfg", ".ini", ""}
HISTORY = re.compile(r"sessions? [0-9]|session-[0-9]|issues? [0-9]|issue-[0-9]", re.I)
#: pages linked from the README that their authors are still writing
PENDING: set[str] = set()


def _bash_lines(text: str) -> list[str]:
    lines, inside = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            inside = line.strip() == "```bash"
            continue
        if inside:
            lines.append(line)
    return lines


def readme_commands(text: str | None = None) -> list[str]:
    """The README's commands: fenced bash lines, continuations joined, comments dropped."""
    joined, current = [], ""
    for line in _bash_lines(README.read_text() if text is None else text):
        current += line.rstrip("\\").rstrip() + " " if line.rstrip().endswith("\\") else line
        if not line.rstrip().endswith("\\"):
            joined.append(current)
            current = ""
    commands = [re.sub(r"\s+#\s.*$", "", c) for c in joined]
    return [" ".join(c.split()) for c in commands if c.strip()]


def readme_command(start: str) -> str:
    """The one README command that starts with ``start`` (so a test runs the README's text)."""
    found = [c for c in readme_commands() if c.startswith(start)]
    assert len(found) == 1, f"README: {len(found)} commands start with {start!r}"
    return found[0]


def _run(command: str, *extra: str, cwd: Path = ROOT, timeout: float = 900):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    argv = command.split()
    assert argv[:2] == ["python", "-m"], command
    return subprocess.run([sys.executable, *argv[1:], *extra], cwd=cwd, env=env, timeout=timeout,
                          capture_output=True, text=True)


# ----------------------------------------------------------------------------- the README


def test_readme_is_at_most_300_lines():
    assert len(README.read_text().splitlines()) <= 300


def test_commands_are_read_from_bash_blocks_only():
    text = ("x\n```bash\npython -m a b \\\n    c=1   # note\npytest -q\n```\n"
            "```text\npython -m not_a_command\n```\n`python -m inline`\n")
    assert readme_commands(text) == ["python -m a b c=1", "pytest -q"]


def test_every_readme_command_is_run_somewhere():
    commands = readme_commands()
    uncovered = [c for c in commands if c not in COVERED]
    assert not uncovered, ("README commands that no test or CI step runs (add each to COVERED "
                           f"in {THIS} with the test that runs it): {uncovered}")
    stale = [c for c in COVERED if c not in commands]
    assert not stale, f"COVERED names commands the README no longer has: {stale}"


def test_each_covering_test_or_ci_step_exists():
    ci = (ROOT / ".ci" / "run").read_text()
    for command, where in COVERED.items():
        if where == ".ci/run":
            assert f"'{command}'" in ci, f".ci/run does not run {command!r} verbatim"
            continue
        path, name = where.split("::")
        source = (ROOT / path).read_text()
        assert re.search(rf"^def {re.escape(name)}\(", source, re.M), f"no test {where}"


def test_the_other_method_on_the_other_task_runs(tmp_path):
    proc = _run(readme_command("python -m tamedpuma.sweep method=cpm"), "scenario.max_steps=20",
                f"output_root={tmp_path}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "cpm on pouring/default" in proc.stdout
    assert len(list(tmp_path.glob("*/summary.json"))) == 1
    # the first run's output shown in the README has the lines a run prints
    shown = re.search(r"```text\n(.*?)```", README.read_text(), re.S).group(1).splitlines()
    printed = proc.stdout.splitlines()
    outcome = re.compile(r"^\w+ on [\w/]+: ")  # "<method> on <task>/<scenario>: ..."
    assert outcome.match(shown[0]) and any(outcome.match(p) for p in printed)
    for words in ("final position error", "min clearance", "controller"):
        assert words in shown[0] and any(words in p for p in printed if outcome.match(p))
    for line in shown[1:]:
        head = line.split(":")[0] + ":"
        assert any(p.startswith(head) for p in printed), f"a run prints no {head!r} line"


def test_the_models_list_names_every_task():
    proc = _run(readme_command("python -m tamedpuma.models list"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    for task in ("tomato", "tomato_position", "pouring", "pouring_position"):
        assert re.search(rf"^{task}\s", proc.stdout, re.M), proc.stdout


def test_the_slurm_command_composes_its_launcher():
    command = readme_command("python -m tamedpuma.sweep +experiment=table1 "
                             "hydra/launcher=submitit_slurm")
    proc = _run(command, "--cfg", "hydra", "-p", "hydra.launcher")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "SlurmLauncher" in proc.stdout and "partition: PARTITION" in proc.stdout
    assert "timeout_min: 30" in proc.stdout and "mem_gb: 4" in proc.stdout


@pytest.mark.slow
def test_the_look_at_a_run_commands_run_in_order(tmp_path):
    """The README's sweep, figures and report, with 20-step runs, into a temporary folder."""
    def here(command: str) -> str:
        return command.replace("runs/look", str(tmp_path / "look")).replace(
            "docs/img", str(tmp_path / "img"))

    sweep = _run(here(readme_command("python -m tamedpuma.sweep -m method=puma,fpm,cpm")),
                 "scenario.max_steps=20")
    assert sweep.returncode == 0, sweep.stderr[-2000:]
    assert len(list((tmp_path / "look").rglob("summary.json"))) == 18
    figures = _run(here(readme_command("python -m tamedpuma.analysis.figures")))
    assert figures.returncode == 0, figures.stderr[-2000:]
    assert {p.name for p in (tmp_path / "img").iterdir()} >= {
        "paths_tomato.png", "clearance_psi_tomato.png", "success_timing.png"}
    report = _run(here(readme_command("python -m tamedpuma.analysis.report")))
    assert report.returncode == 0, report.stderr[-2000:]
    assert "## Table 1" in (tmp_path / "look" / "report.md").read_text()


# ----------------------------------------------------------------------------- the pages


def _links(path: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    return [m for m in re.findall(r"\]\(([^)\s]+)\)", text)
            if not re.match(r"[a-z]+:", m) and not m.startswith("#")]


@pytest.mark.parametrize("page", [README, *sorted(DOCS.glob("*.md"))], ids=lambda p: p.name)
def test_links_resolve(page):
    for link in _links(page):
        target = (page.parent / link.split("#")[0]).resolve()
        if target.relative_to(ROOT).as_posix() in PENDING:
            continue
        assert target.exists(), f"{page.name}: broken link {link}"


def test_the_readme_links_every_page():
    linked = {(README.parent / link.split("#")[0]).resolve() for link in _links(README)}
    for page in DOCS.glob("*.md"):
        assert page.resolve() in linked, f"README does not link {page.relative_to(ROOT)}"


def test_configuration_page_is_current():
    from tamedpuma.app import config_page

    assert (DOCS / "configuration.md").read_text() == config_page.render(), (
        "docs/configuration.md is stale: run python -m tamedpuma.app.config_page")


def test_configuration_page_has_every_method_and_group():
    from tamedpuma import methods
    from tamedpuma.app import schema

    text = (DOCS / "configuration.md").read_text()
    for name in schema.METHODS:  # the package's own (a plugin documents its own)
        assert (f"## Method `{name}`" in text) == (name in methods.builtin()), name
    for key in ("scenario.max_steps", "robot.limit_tolerance", "clutter.total", "sim.substep",
                "method.forcing.stall_pull", "puma.train.iterations", "save_every"):
        assert f"| `{key}` |" in text, key


def test_the_configuration_page_describes_every_config_group():
    from tamedpuma.app import config_page
    from tamedpuma.paths import CONF_DIR

    groups = {p.name for p in CONF_DIR.iterdir() if p.is_dir()} - {"hydra"}
    assert groups | {"hydra/launcher"} == set(config_page.GROUPS), "a new group needs its line"
    assert config_page.collapsed(["a", "t/00", "t/01", "t/02", "t/04", "x1"]) == (
        "`a`, `t/00` … `t/02`, `t/04`, `x1`")


def test_the_benchmark_sections_its_command_rewrites_are_there():
    text = (ROOT / "BENCHMARKS.md").read_text()
    for title in ("Controller step", "Controller step in episodes", "Fabrics"):
        assert re.search(rf"^## {title}$", text, re.M), title


# ----------------------------------------------------------------------------- history


def _history_free_files() -> list[Path]:
    """Every tracked text file (``git ls-files``; without git, the files below the checkout
    outside hidden folders and run outputs)."""
    try:
        listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                                check=True).stdout.splitlines()
        files = [ROOT / name for name in listed]
    except (OSError, subprocess.CalledProcessError):
        files = [p for p in ROOT.rglob("*") if not any(
            part.startswith(".") or part in ("runs", "__pycache__") for part in
            p.relative_to(ROOT).parts[:-1])]
    return sorted(p for p in files if p.is_file() and p.suffix in TEXT_SUFFIXES)


def test_the_history_check_sees_its_files():
    files = {p.relative_to(ROOT).as_posix() for p in _history_free_files()}
    assert {"README.md", "CHANGELOG.md", "tests/test_docs.py", "tamedpuma/robot/ground.py",
            "tamedpuma/fabrics/discrete.py", "tamedpuma/conf/scenario/random.yaml"} <= files
    assert {"tamedpuma/fabrics/compiled.py", "tamedpuma/methods/_configuration_pull.py",
            ".ci/run", "pyproject.toml"} <= files  # every tracked text file
    assert HISTORY.search(f"as in Session {12}") and HISTORY.search(f"issue {7}")
    assert not HISTORY.search("a session fixture")


def test_no_session_or_issue_numbers():
    found = [f"{p.relative_to(ROOT)}:{i}: {line.strip()[:80]}"
             for p in _history_free_files()
             for i, line in enumerate(p.read_text(errors="replace").splitlines(), start=1)
             if HISTORY.search(line)]
    assert not found, "history belongs to git and CHANGELOG.md:\n" + "\n".join(found)


# ----------------------------------------------------------------------------- the results page


def _fake_runs(tmp_path: Path) -> Path:
    """Two runs' summaries (one with a model) and the analysis's table1.md."""
    runs = tmp_path / "runs"
    for i, model in enumerate(({"model_name": "tomato", "model_sha256": "ab" * 32,
                                "model_origin": "cache"}, None)):
        (runs / f"run{i}").mkdir(parents=True)
        (runs / f"run{i}" / "summary.json").write_text(json.dumps({"model": model}))
    (runs / "table1.md").write_text("| method | success |\n|---|---|\n| fpm | 0.97 |\n")
    return runs


def test_the_results_page_block_is_rewritten_from_the_analysis_with_its_provenance(tmp_path):
    from tamedpuma.app import results_page

    page = tmp_path / "results.md"
    page.write_text("# Results\n\n<!-- result: table1 -->\nold 1.00\n<!-- /result -->\n\n"
                    "<!-- result: scaling -->\nkept\n<!-- /result -->\n")
    assert results_page.main(["table1", str(_fake_runs(tmp_path)), "--page", str(page)]) == 0
    text = page.read_text()
    table1 = text[text.index("<!-- result: table1 -->"):text.index("<!-- result: scaling")]
    assert "old 1.00" not in table1 and "| fpm | 0.97 |" in table1
    assert "python -m tamedpuma.sweep +experiment=table1" in table1
    assert "(2 runs)" in table1 and f"tomato `{'ab' * 6}` (cache)" in table1
    assert re.search(r"- date: \d{4}-\d\d-\d\d", table1)
    assert re.search(r"- code: `[0-9a-f]{7,}(-dirty)?`", table1)
    assert "- machine: " in table1 and " cores, Python " in table1
    assert "<!-- result: scaling -->\nkept\n<!-- /result -->" in text
    assert text.count("<!-- /result -->") == 2


def test_the_results_page_names_the_revision_and_machine_the_runs_record(tmp_path):
    """Runs that record their code revision and machine (summary.json, schema 2) are named by
    those, not by the host that writes the page."""
    from tamedpuma.app import results_page

    runs = _fake_runs(tmp_path)
    machine = {"cpu": "Test CPU 9000", "cores": 64, "python": "3.99.0",
               "packages": {"torch": "9.9.9+cpu"}}
    for i, rev in enumerate(("1234567" + "0" * 33, "89abcde" + "f" * 33)):
        path = runs / f"run{i}" / "summary.json"
        path.write_text(json.dumps({**json.loads(path.read_text()), "code_revision": rev,
                                    "machine": machine}))
    page = tmp_path / "results.md"
    page.write_text("# Results\n")
    assert results_page.main(["table1", str(runs), "--page", str(page)]) == 0
    text = page.read_text()
    assert "- code: `1234567`, `89abcde`\n" in text
    assert "- machine: Test CPU 9000, 64 cores, Python 3.99.0, torch 9.9.9+cpu\n" in text
    assert results_page.HOST not in text


def test_the_results_page_refuses_a_folder_without_the_analysis_in_one_line(tmp_path, capsys):
    from tamedpuma.app import results_page

    runs = _fake_runs(tmp_path)
    page = tmp_path / "results.md"
    page.write_text("# Results\n")
    assert results_page.main(["disturbance", str(runs), "--page", str(page)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "disturbance.md not found" in err and "\n" not in err
    assert page.read_text() == "# Results\n"
    assert results_page.main(["table1", str(tmp_path / "nope"), "--page", str(page)]) == 2


def test_installed_the_pages_go_to_docs_of_the_current_folder(tmp_path, monkeypatch, capsys):
    """An installed package (no pyproject.toml beside it: site-packages) writes the results and
    configuration pages into docs/ of the working directory, never beside site-packages, and
    names its version, not the git revision of whatever repository holds site-packages."""
    from tamedpuma import paths
    from tamedpuma.app import config_page, results_page
    from tamedpuma.app.models import code_revision

    runs = _fake_runs(tmp_path)
    monkeypatch.setattr(paths, "CHECKOUT_ROOT", tmp_path / "site-packages")
    here = tmp_path / "elsewhere"
    here.mkdir()
    monkeypatch.chdir(here)
    assert results_page.main(["table1", str(runs)]) == 0
    text = (here / "docs" / "results.md").read_text()
    assert "| fpm | 0.97 |" in text and "- code: `tamedpuma " in text  # the version, no git
    assert code_revision().startswith("tamedpuma ")  # what its runs record, shown whole
    assert results_page.run_revisions([{"code_revision": code_revision()}]) == (
        f"`{code_revision()}`")
    capsys.readouterr()
    assert config_page.main(["--check"]) == 1  # no page in this folder yet
    assert capsys.readouterr().out.startswith(f"{here / 'docs' / 'configuration.md'}: stale")
    assert not (tmp_path / "docs").exists()


def test_the_ablation_block_is_written_into_the_method_page(tmp_path):
    """The ablation's tables and figure go into docs/method.md (its own page), replacing the
    block and leaving the rest of the page as it is."""
    from tamedpuma.app import results_page

    runs = _fake_runs(tmp_path)
    (runs / "ablation.md").write_text("#### Both suites\n\n| method | removed |\n|--|--|\n"
                                      "| fpm | stall_pull |\n")
    (runs / "ablation.png").write_bytes(b"\x89PNG fake")
    page = tmp_path / "docs" / "method.md"
    page.parent.mkdir()
    page.write_text("# The method\n\n<!-- result: ablation -->\nold\n<!-- /result -->\n\nafter\n")
    assert results_page.main(["ablation", str(runs), "--page", str(page)]) == 0
    text = page.read_text()
    assert "| fpm | stall_pull |" in text and "\nold\n" not in text
    assert text.startswith("# The method\n") and text.endswith("<!-- /result -->\n\nafter\n")
    assert "python -m tamedpuma.ablation" in text and "![ablation](img/ablation.png)" in text
    assert (tmp_path / "docs" / "img" / "ablation.png").read_bytes() == b"\x89PNG fake"
    assert results_page.EXPERIMENTS["ablation"].page == Path("docs") / "method.md"


def test_every_results_block_names_its_provenance():
    text = (DOCS / "results.md").read_text() + (DOCS / "method.md").read_text()
    blocks = re.findall(r"<!-- result: ([a-z0-9]+) -->(.*?)<!-- /result -->", text, re.S)
    assert {name for name, _ in blocks} >= {"table1", "scaling", "random", "disturbance",
                                            "figures", "ablation"}
    for name, body in blocks:
        for field in ("- command: ", "- date: ", "- machine: ", "- code: ", "- models"):
            assert field in body, f"results.md block {name}: no {field.strip()}"


def test_the_readmes_table1_is_written_beside_the_papers_from_the_analysis(tmp_path, capsys):
    from tamedpuma.app import readme_table, results_page

    runs = _fake_runs(tmp_path)
    (runs / "table1.md").write_text(
        "| method | runs | success (paper) | success (whole body) | with orientation (paper / "
        "whole body) | converged (paper / whole body) | path difference to PUMA [m] |\n"
        "|:--|:--|:--|:--|:--|:--|:--|\n"
        "| fabrics | 30 | 0.87 | 0.73 | 0.03 / 0.03 | 0.87 / 0.73 | 0.12 ± 0.06 |\n"
        "| my_method | 30 | 0.50 | 0.40 | 0.20 / 0.10 | 0.45 / 0.35 | 0.30 ± 0.10 |\n")
    page, readme = tmp_path / "results.md", tmp_path / "README.md"
    page.write_text("# Results\n")
    readme.write_text("# x\n\nbefore\n<!-- result: table1-summary -->\nold 0.99\n"
                      "<!-- /result -->\nafter\n")
    argv = ["table1", str(runs), "--page", str(page), "--readme", str(readme)]
    assert results_page.main(argv) == 0
    text = readme.read_text()
    assert text.startswith("# x\n\nbefore\n<!-- result: table1-summary -->\n")
    assert text.endswith("<!-- /result -->\nafter\n") and "old 0.99" not in text
    assert "| Fabrics | 0.87 | 0.73 | 0.03 | 0.87 | 0.12 ± 0.06 | 0.83 / 0.22 ± 0.27 |" in text
    assert "| `my_method` | 0.50 | 0.40 | 0.20 | 0.45 | 0.30 ± 0.10 | — |" in text
    assert "(2 runs;" in text and f"tomato `{'ab' * 6}` (cache)" in text
    assert readme_table.PAPER["fpm"] == ("1.00", "0.02 ± 0.04")  # the paper's Table 1
    # a README without the block, or --readme with another experiment: one line, status 2
    readme.write_text("# no block\n")
    assert results_page.main(argv) == 2
    assert results_page.main(["scaling", str(runs), "--page", str(page), "--readme",
                              str(readme)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("error: ") and "table1-summary" in err[0]
    assert err[1] == "error: --readme goes with the table1 block only"


def test_the_readmes_table1_block_is_the_analysis_output():
    """The README's Table 1 is a generated block, never typed between its markers by hand:
    its rows have the columns the writer gives them and its first line is the provenance."""
    from tamedpuma.app import readme_table

    text = (ROOT / "README.md").read_text()
    start = text.index("<!-- result: table1-summary -->")
    body = text[start:text.index("<!-- /result -->", start)].splitlines()[1:]
    assert body[0].startswith("Measured ") and "code `" in body[0]
    rows = readme_table.markdown_rows("\n".join(body))
    assert rows and all(len(r) == len(readme_table.COLUMNS) + 2 for r in rows)
    assert {r["method"] for r in rows} >= {"PUMA", "Modulation-IK", "Fabrics", "FPM", "CPM"}


def test_a_measuring_commands_block_is_written_from_its_stamped_json(tmp_path, capsys):
    """The learner table's and the LASA benchmark's blocks come from the JSON their command
    stamped (command, date, machine, code, load); an unstamped JSON is refused in one line."""
    from tamedpuma.app import provenance, results_page

    row = {"set": "tomato", "order": 2, "seed": 0, "n_demos": 10, "unit": "m", "dtw": 0.008,
           "dtw_worst": 0.02, "frechet": 0.015, "converged": 1.0, "compatible": 0.999,
           "iterations": 900, "train_s": 70.0, "wall_s": 80.0, "cpu_s": 79.0,
           "gates_failed": []}
    bad = {**row, "set": "pouring_v2", "seed": 1, "dtw": 0.021, "train_s": 130.0}
    stamp = provenance.with_end(provenance.stamp("python -m tamedpuma.train --table t.md"))
    table = tmp_path / "learner.json"
    table.write_text(json.dumps({"provenance": stamp, "rows": [row, bad]}))
    page = tmp_path / "BENCHMARKS.md"
    page.write_text("# Benchmarks\n\n<!-- result: learner -->\nold\n<!-- /result -->\nkept\n")
    assert results_page.main(["learner", str(table), "--page", str(page)]) == 0
    text = page.read_text()
    assert "old" not in text and text.endswith("<!-- /result -->\nkept\n")
    for field in ("- command: `python -m tamedpuma.train --table t.md`", "- date: ",
                  "- machine: ", "- code: `", "- models: ", "load average"):
        assert field in text, field
    assert "| tomato | 2 | 0 | 10 | 0.80 cm | 2.00 cm |" in text
    assert "met by 1 of 2 models; missed by pouring_v2 order 2 seed 1 (DTW)" in text
    assert ("Median training of a second-order model: 100 s over the table's 2 (target ≤ 90 s: "
            "missed).") in text
    table.write_text(json.dumps([row]))  # rows without the command's stamp
    assert results_page.main(["learner", str(table), "--page", str(page)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "no stamped rows" in err and "\n" not in err

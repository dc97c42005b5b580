"""Frozen suites: each suite experiment carries a name, a version and seed 0; its scenarios
and seeds are pinned per version (a change without a new version fails here); every run's
summary records the suite, the summary layout's version, the code revision, the model's sha256
and the machine; summaries of older layouts are read, newer ones refused in one line."""

from __future__ import annotations

import hashlib
import json
import logging
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf

from tamedpuma.analysis.summaries import load_summaries
from tamedpuma.app import schema
from tamedpuma.errors import ConfigError, LogError
from tamedpuma.paths import CONF_DIR
from tamedpuma.runlog import SUMMARY_SCHEMA_VERSION, upgrade_summary

REPO = Path(__file__).resolve().parents[1]
#: experiment -> (suite, version, fingerprint of its scenarios and seeds). A change to a suite's
#: scenarios or seeds is a new version: bump ``suite.version`` in the experiment files of that
#: suite and pin the new fingerprint here (runs of the old version are then not compared). The
#: fingerprint covers the configs; what the scenario generator makes of a seed is its own tests'.
SUITES = {
    "table1": ("table1", 1,
        "c5eb103f7de216f600331d8324ffe23fe40ed25d03b99bb8bd65118a2892d00a"),
    "table1_tomato": ("table1", 1,
        "9eb8968eb7ccc2787871032e4d3aa833e2c5721dba4a6a58df3d2a1d165dfd92"),
    "table1_pouring": ("table1", 1,
        "9750188ddf55d456c495be3564181f73ab9ba9b952a7f2f4e8364859fe1f0cc5"),
    "ablation": ("table1", 1,
        "8587c8809d9f47ca14cb35929342b19b11253eb6f8c6e48a3281368d8e50c764"),
    # version 2: the generator redraws a goal that moves out of the arm's reach
    "random": ("random", 2,
        "f0687b2ec7c406b1a49dbb7cb2a2b3053def03e0f58b0751d99287843469e32d"),
    "ablation_random": ("random", 2,
        "e7e862b848039f29fe7ef7a8f2b3a308d62bfb03b2e2d39cd0fabc6ae1d7f09f"),
    "scaling": ("scaling", 1,
        "41d08cf24cf9bf97a4b0c73530e111f88ecfee8a69837b81259ce9577d9925c5"),
    # the push's link comes from robot.ee_link (lbr_iiwa_link_7 on the iiwa, as the option named
    # it before): the same scenarios, the runs identical, so the same version
    "disturbance": ("disturbance", 1,
        "4bedd2a491be5d77bd3b5717172c0e50b43273ee8d528d112aa38a3277640d6a"),
}
#: sweep parameters that choose the methods, not the scenarios
_METHOD_PARAMS = {"method", "ablation", "without_obstacles"}


def _option_text(group: str, name: str) -> dict:
    """An option file's text, with the scenario a case file selects."""
    text = (CONF_DIR / group / f"{name}.yaml").read_text()
    out = {f"{group}/{name}": text}
    for line in text.splitlines():
        if "override /scenario:" in line:
            scenario = line.split(":", 1)[1].strip()
            out.update(_option_text("scenario", scenario))
    return out


def fingerprint(experiment: str) -> str:
    """sha256 of what decides a suite's scenarios: the experiment's sweep parameters other than
    the methods, its other keys (seed, clutter, ...), and the text of every case, scenario and
    disturbance option it names."""
    cfg = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "experiment" / f"{experiment}.yaml"))
    params = {k.lstrip("+"): v for k, v in cfg["hydra"]["sweeper"]["params"].items()
              if k.lstrip("+") not in _METHOD_PARAMS}
    files = {}
    for entry in cfg.get("defaults", []):
        if isinstance(entry, dict):
            (key, value), = entry.items()
            group = key.split()[-1].strip("/")
            if group in ("case", "scenario", "disturbance"):
                files.update(_option_text(group, value))
    for key, values in params.items():
        if key in ("case", "scenario", "disturbance"):
            for value in str(values).split(","):
                files.update(_option_text(key, value))
    top = {k: v for k, v in cfg.items() if k not in ("hydra", "defaults", "suite")}
    text = json.dumps({"params": params, "top": top, "files": files}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


@pytest.fixture(scope="module")
def composed():
    GlobalHydra.instance().clear()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        yield lambda overrides: compose("sweep", overrides=overrides, return_hydra_config=True)
    GlobalHydra.instance().clear()


@pytest.mark.parametrize("experiment", sorted(SUITES))
def test_every_suite_has_its_name_version_and_seed(composed, experiment):
    suite, version, _ = SUITES[experiment]
    cfg = composed([f"+experiment={experiment}"])
    run = schema.run_config(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]))
    assert (run.suite.name, run.suite.version, run.seed) == (suite, version, 0)


@pytest.mark.parametrize("experiment", sorted(SUITES))
def test_a_suites_scenarios_and_seeds_are_those_of_its_version(experiment):
    suite, version, pinned = SUITES[experiment]
    assert fingerprint(experiment) == pinned, (
        f"{experiment}: the scenarios or seeds of suite {suite} version {version} changed; "
        "give the suite a new version (suite.version) and pin the new fingerprint")


def test_every_experiment_that_sweeps_scenarios_is_a_suite():
    for path in (CONF_DIR / "experiment").glob("*.yaml"):
        cfg = OmegaConf.load(path)
        if "suite" in cfg:
            assert path.stem in SUITES, f"{path.stem}: pin its fingerprint in SUITES"


def test_an_older_summary_is_read_and_a_newer_one_refused(tmp_path, caplog):
    old = {"status": "complete", "method": "fpm", "step_compute_ms": [1.0]}
    upgraded = upgrade_summary(old)
    assert upgraded["schema_version"] == SUMMARY_SCHEMA_VERSION
    assert upgraded["suite"] is None and upgraded["machine"] is None
    with pytest.raises(LogError, match=f"schema version {SUMMARY_SCHEMA_VERSION + 1}.*up to "
                                       f"{SUMMARY_SCHEMA_VERSION}"):
        upgrade_summary({**old, "schema_version": SUMMARY_SCHEMA_VERSION + 1})
    for name, summary in (("old", old), ("new", {**old, "schema_version": 99})):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps(summary))
    with caplog.at_level(logging.WARNING):
        frame, _ = load_summaries(tmp_path)
    assert list(frame["path"]) == [str(tmp_path / "old")] and frame["suite"].isna().all()
    assert "schema version 99" in caplog.text and frame.attrs["skipped"]


def test_a_runs_summary_records_suite_layout_revision_model_and_machine(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "tamedpuma.sweep", "method=puma",
                           "+case=tomato_03", "scenario.max_steps=5", "recorder=none",
                           "suite.name=table1", "suite.version=1", f"output_root={tmp_path}"],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    (path,) = tmp_path.rglob("summary.json")
    summary = json.loads(path.read_text())
    assert summary["schema_version"] == SUMMARY_SCHEMA_VERSION
    assert summary["suite"] == {"name": "table1", "version": 1}
    assert summary["code_revision"] and len(summary["model"]["model_sha256"]) == 64
    machine = summary["machine"]
    assert machine["cores"] >= 1 and machine["python"].count(".") == 2
    assert machine["packages"]["numpy"]


@pytest.mark.parametrize("kwargs, match", [
    ({"name": "table1", "version": 0}, "suite.version must be an integer >= 1"),
    ({"name": "table1"}, "suite must be a name and a version together"),
    ({"version": 1}, "suite must be a name and a version together")])
def test_a_half_set_suite_is_refused(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        schema.SuiteSchema(**kwargs)

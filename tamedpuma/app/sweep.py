"""``python -m tamedpuma.sweep [overrides]``: run configured episodes into ``runs/``.

One episode by default (``conf/sweep.yaml``); Hydra's multirun sweeps the groups, e.g.::

    python -m tamedpuma.sweep -m method=joint_attractor,fabrics task=tomato,pouring

Each run folder holds ``episode.mcap`` (Foxglove), ``episode.rrd`` (Rerun), ``summary.json`` and
Hydra's ``.hydra/`` (the resolved config and the overrides). The entry point is the only place
that imports Hydra; a user mistake (unknown option, malformed override, bad scenario, unwritable
output folder) prints one line ``error: ...`` on stderr and exits with status 2.
"""

from __future__ import annotations

import json
import logging
import signal
import sys
from dataclasses import dataclass
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from tamedpuma.app.cli import fail, precheck_overrides
from tamedpuma.app.config import CONF_DIR
from tamedpuma.errors import ConfigError, TamedPumaError

log = logging.getLogger("tamedpuma.sweep")


def _recorders(cfg: DictConfig, run_dir: Path):
    from tamedpuma.recording.mcap_writer import McapRecorder
    from tamedpuma.recording.rerun_writer import RerunRecorder

    recorders, files = [], {}
    if cfg.recorder.mcap:
        files["mcap"] = run_dir / "episode.mcap"
        recorders.append(McapRecorder(files["mcap"], flush_every=int(cfg.recorder.flush_every)))
    if cfg.recorder.rerun:
        files["rrd"] = run_dir / "episode.rrd"
        recorders.append(RerunRecorder(files["rrd"]))
    return recorders, files


@dataclass(frozen=True)
class Built:
    """Everything one episode needs, built from the config before anything runs."""

    spec: object
    scenario: object
    controller: object
    sim_config: object
    disturbance: object = None
    model: object = None  # the trained model the method uses (store.ModelChoice) or None


def build(cfg: DictConfig) -> Built:
    """Config -> robot, scenario, controller, simulator settings. Any invalid value (wrong type,
    missing key, bad number) becomes a :class:`ConfigError` with a one-line message."""
    from tamedpuma import methods
    from tamedpuma.app.schema import validate
    from tamedpuma.puma import store
    from tamedpuma.robot.kinematics import Kinematics, robot_spec_from_config
    from tamedpuma.worlds import demo_scenarios
    from tamedpuma.worlds.bullet import Disturbance, SimConfig
    from tamedpuma.worlds.scenarios import build_scenario

    validate(cfg)
    try:
        plain = OmegaConf.to_container(cfg, resolve=True)
        spec = robot_spec_from_config(plain["robot"])
        kinematics = Kinematics(spec)
        plain = demo_scenarios.apply(plain, kinematics)  # derived goal, generated scenario
        if plain["robot"].get("null_space") and isinstance(plain["method"].get("null_space"),
                                                           dict):
            # the robot config's "elbow up" link and target replace the method's (iiwa) ones
            plain["method"]["null_space"] = {**plain["method"]["null_space"],
                                             **plain["robot"]["null_space"]}
        scenario = build_scenario(plain, spec, kinematics)
        model = store.resolve_for_method(plain["method"])
        if model is not None:  # the method loads exactly the file that is recorded
            plain["method"]["checkpoint"] = str(model.path)
        controller = methods.make(cfg.method.name, plain["method"], kinematics)
        sim_config = SimConfig(**plain["sim"])
        disturbance = Disturbance(**(plain.get("disturbance") or {}))
    except TamedPumaError:
        raise
    except (ValueError, TypeError, KeyError) as exc:
        raise ConfigError(f"invalid configuration: {type(exc).__name__}: {exc}") from exc
    return Built(spec, scenario, controller, sim_config, disturbance, model)


def run_one(cfg: DictConfig, run_dir: Path) -> dict:
    """Config -> scenario -> controller -> simulator -> recorders -> files. Returns the summary."""
    from tamedpuma.episode import run_episode
    from tamedpuma.recording.records import RunInfo
    from tamedpuma.worlds.bullet import Simulator

    built = build(cfg)
    spec, scenario = built.spec, built.scenario
    recorders, files = _recorders(cfg, run_dir)
    info = RunInfo(run_id=run_dir.name, method=cfg.method.name, task=cfg.task.name,
                   scenario_name=scenario.name, seed=int(cfg.seed),
                   config_yaml=OmegaConf.to_yaml(cfg, resolve=True), urdf_path=spec.urdf_path,
                   joint_names=spec.joint_names, link_names=spec.link_names,
                   body_sphere_radii=spec.sphere_radii, dt=scenario.dt,
                   velocity_limits=spec.qd_max,
                   model=built.model.metadata() if built.model else {})
    with Simulator(spec, built.sim_config, built.disturbance) as sim:
        result = run_episode(scenario, built.controller, sim, recorders, info,
                             stop_on_success=bool(cfg.stop_on_success),
                             settle_time=float(cfg.get("settle_time", 0.0)))
    summary = {"run_dir": str(run_dir), "method": cfg.method.name,
               "method_label": method_label(cfg.method), "task": cfg.task.name,
               "scenario": scenario.name, "seed": int(cfg.seed),
               "n_obstacles": len(scenario.obstacles),
               "disturbance": built.disturbance.name or built.disturbance.kind,
               "control": built.sim_config.control,
               "stop_reason": result.stop_reason, **result.metrics.as_dict(),
               "files": {k: str(v) for k, v in files.items()},
               "model": built.model.metadata() if built.model else None,
               # every step's controller time [ms] (pooled statistics across runs)
               "step_compute_ms": [round(float(v), 5) for v in result.compute_ms]}
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def method_label(method_cfg) -> str:
    """The name a method's runs carry in tables: ``label`` if the method config sets one (e.g.
    ``cpm_literal``), else its ``name``."""
    return str(method_cfg.get("label") or method_cfg.name)


def _report(summary: dict) -> None:
    m = summary
    # whole-body success implies paper success (a superset of the same conditions)
    if m["success_whole_body"]:
        outcome = "success"
    elif m["success_paper"]:
        outcome = f"success under the paper criterion only [{m['failure_whole_body']}]"
    else:
        outcome = f"no success [{m['failure_whole_body']}]"
    print(f"{m['method_label']} on {m['task']}/{m['scenario']}: {outcome} after {m['steps']} steps "
          f"({m['duration_s']:.2f} s), final position error {m['final_position_error_m']:.4f} m, "
          f"min clearance {m['min_clearance_m']:.3f} m, "
          f"controller {m['compute_ms_median']:.3f} ms (median)")
    if m.get("model"):
        mm = m["model"]
        print(f"model: {mm['model_origin']} {mm['model_path']} (sha256 "
              f"{mm['model_sha256'][:12]}, trained on {mm['model_data']} data "
              f"{mm['model_data_source']})")
    print(f"run folder: {m['run_dir']}")
    for kind, path in m["files"].items():
        print(f"  {kind}: {path}")
    print(f"  summary: {Path(m['run_dir']) / 'summary.json'}")
    if "rrd" in m["files"]:
        print(f"replay: rerun {m['files']['rrd']}")
    print(f"replay: python -m tamedpuma.replay {m['run_dir']}")


@hydra.main(config_path=str(CONF_DIR), config_name="sweep", version_base="1.3")
def _hydra_main(cfg: DictConfig) -> None:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        summary = run_one(cfg, run_dir)
    except TamedPumaError as exc:
        fail(str(exc))
    _report(summary)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    # a killed run (SIGTERM) unwinds normally, so recorders close their files as incomplete
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    error = precheck_overrides("sweep", argv)
    if error:
        fail(error)
    _hydra_main()


if __name__ == "__main__":
    main()

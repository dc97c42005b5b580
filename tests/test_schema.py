"""The typed configuration (tamedpuma/app/schema.py): every shipped YAML loads against the schema,
a key the schema does not know is refused, every out-of-range value is refused naming the key and
the limit, and no library code keeps a default of its own (``cfg.get(key, default)``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf

from tamedpuma import methods
from tamedpuma.app import schema
from tamedpuma.app.config import CONF_DIR
from tamedpuma.errors import ConfigError
from tamedpuma.methods import cpm
from tamedpuma.worlds.demo_scenarios import DemoScenarioConfig
from tamedpuma.worlds.random_scenarios import RandomParams

PKG = Path(__file__).resolve().parents[1] / "tamedpuma"


@pytest.fixture(scope="module")
def hydra_conf():
    GlobalHydra.instance().clear()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        yield
    GlobalHydra.instance().clear()


def _options(group: str) -> list[str]:
    return sorted(p.relative_to(CONF_DIR / group).with_suffix("").as_posix()
                  for p in (CONF_DIR / group).rglob("*.yaml"))


def _run_overrides(group: str, option: str) -> list[str]:
    if group == "scenario" and "/" in option:
        return [f"scenario={option}", f"task={option.split('/')[0]}"]
    if group == "fabric":
        return ["method=fabrics", f"fabric@method.fabric={option}"]
    if group in ("experiment", "case", "ablation"):
        return [f"+{group}={option}"]
    return [f"{group}={option}"]


RUN_GROUPS = ("robot", "task", "scenario", "method", "recorder", "sim", "fabric", "experiment",
              "case", "disturbance", "ablation")
RUN_CASES = [(g, o) for g in RUN_GROUPS for o in _options(g) if (g, o) != ("task", "lasa")]
TRAIN_CASES = [(g, o) for g in ("task", "puma") for o in _options(g)]


def test_every_yaml_is_covered():
    groups = {p.name for p in CONF_DIR.iterdir() if p.is_dir()}
    # conf/hydra/ holds launcher presets (Hydra's own schema validates them)
    assert groups == {*RUN_GROUPS, "puma", "hydra"}, "a new config group needs its case here"
    assert len(RUN_CASES) + len(TRAIN_CASES) > 40
    # every top-level config (an entry point's) has its schema
    assert {p.stem for p in CONF_DIR.glob("*.yaml")} == set(schema.CONFIGS)


@pytest.mark.parametrize("group,option", RUN_CASES, ids=lambda v: str(v))
def test_run_yaml_loads_against_the_schema(hydra_conf, group, option):
    cfg = compose("sweep", overrides=_run_overrides(group, option))
    run = schema.run_config(cfg)
    assert isinstance(run.method, schema.METHODS[run.method.name])
    # typed section by section: the object typing the whole config at once gives
    plain = OmegaConf.to_container(cfg, resolve=True)
    whole = schema.typed(schema.RunConfig, {**plain, "method": {}})
    whole.method = schema.method_options(plain["method"])
    assert type(run) is type(whole) and run == whole
    assert run.scenario.dt > 0 and run.sim.substep > 0
    sc = run.scenario
    if sc.random is not None:  # typed by the schema: the generator's own parameters
        assert isinstance(sc.random, schema.RandomSchema)
        RandomParams(**schema.as_dict(sc.random))
    if sc.generator is not None:
        assert isinstance(sc.generator, schema.DemoGeneratorSchema)
        gen = schema.as_dict(sc.generator)
        assert gen.pop("kind") == "demos"
        DemoScenarioConfig(**gen)


@pytest.mark.parametrize("group,option", TRAIN_CASES, ids=lambda v: str(v))
def test_train_yaml_loads_against_the_schema(hydra_conf, group, option):
    cfg = schema.train_config(compose("train", overrides=[f"{group}={option}"]))
    assert cfg.puma.train.iterations > 0


@pytest.mark.parametrize("robot", _options("robot"))
def test_body_model_yaml_loads_against_the_schema(hydra_conf, robot):
    cfg = schema.body_model_config(compose("body_model", overrides=[f"robot={robot}"]))
    assert cfg.robot.name == robot and cfg.max_spheres >= 1
    assert all(len(s.offset) == 3 for s in cfg.robot.spheres)  # BodySphere's default filled in


@pytest.mark.parametrize("override,match", [
    ("+max_sphere=2", r"max_sphere: unknown key"),
    ("+robot.body_model.skipp=[x]", r"robot\.body_model\.skipp: unknown key"),
    ("max_spheres=0", r"max_spheres must be in \[1, 100\]"),
    ("tolerance=-1", r"tolerance must be a finite number >= 0"),
])
def test_a_body_model_mistake_is_refused(hydra_conf, override, match):
    with pytest.raises(ConfigError, match=match):
        schema.body_model_config(compose("body_model", overrides=[override]))


def test_every_method_has_a_schema():
    assert set(methods.available()) == set(schema.METHODS)


@pytest.mark.parametrize("method", sorted(schema.METHODS))
def test_a_misspelt_method_option_is_refused(hydra_conf, method):
    from tamedpuma.app.compose import with_plugins  # an installed plugin's method too

    cfg = compose("sweep", overrides=with_plugins([f"method={method}", "+method.stifness=100"]))
    with pytest.raises(ConfigError, match=r"method\.stifness: unknown key"):
        schema.run_config(cfg)


@pytest.mark.parametrize("override,match", [
    ("+robot.colour=red", r"robot\.colour: unknown key"),
    ("+scenario.dtt=0.01", r"scenario\.dtt: unknown key"),
    ("+sim.substeps=0.001", r"sim\.substeps: unknown key"),
    ("+recorder.csv=true", r"recorder\.csv: unknown key"),
    ("+clutter.size=0.1", r"clutter\.size: unknown key"),
    ("+task.goal=1", r"task\.goal: unknown key"),
    ("+task.workspace.max_angel=1", r"task\.workspace\.max_angel: unknown key"),
    ("+sedd=1", r"sedd: unknown key"),
    ("+disturbance.forse=1", r"disturbance\.forse: unknown key"),
    ("+robot.spheres.0.offsett=[0,0,0]", r"offsett: unknown key.*SphereSchema"),
    ("robot.spheres.0.radius=-0.1", r"robot\.spheres\.radius must be a finite number > 0"),
    ("+robot.null_space.stiffness=2", r"robot\.null_space\.stiffness: unknown key"),
    ("sim.control=torque", r"sim\.control must be one of"),
    ("method=fpm", None),
])
def test_an_unknown_key_is_refused(hydra_conf, override, match):
    cfg = compose("sweep", overrides=[override])
    if match is None:
        schema.run_config(cfg)  # the control case loads
        return
    with pytest.raises(ConfigError, match=match):
        schema.run_config(cfg)


@pytest.mark.parametrize("overrides,match", [
    (["scenario=random", "+scenario.random.start_sigmaa=0.2"],
     r"scenario\.random\.start_sigmaa: unknown key"),
    (["scenario=random", "scenario.random.radius_range=[0.07,0.04]"],
     r"scenario\.random\.radius_range must be \[low, high\]"),
    (["scenario=random", "scenario.random.max_tries=1.5"], r"scenario\.random\.max_tries"),
    (["scenario=random", "scenario.start_kind=somewhere"], r"scenario\.start_kind must be"),
    (["task=tomato", "scenario=from_demos", "+scenario.generator.n_obstacle=2"],
     r"scenario\.generator\.n_obstacle: unknown key"),
    (["task=tomato", "scenario=from_demos", "scenario.generator.kind=grid"],
     r"scenario\.generator\.kind must be demos"),
    (["scenario=random", "scenario.random.start_sigma=0.2", "scenario.start_kind=anywhere"],
     None),
])
def test_the_scenario_generators_blocks_are_checked(hydra_conf, overrides, match):
    """scenario.random and scenario.generator are typed by the generators' own dataclasses."""
    from hydra.errors import HydraException

    if match is None:  # the control case loads, with the override and the other defaults
        run = schema.run_config(compose("sweep", overrides=overrides))
        assert run.scenario.random.start_sigma == 0.2
        assert run.scenario.random.radius_range == list(RandomParams().radius_range)
        return
    with pytest.raises((ConfigError, HydraException), match=match):  # wrong types: at compose
        schema.run_config(compose("sweep", overrides=overrides))


@pytest.mark.parametrize("override,match", [
    ("scenario.dt=inf", r"scenario\.dt must be a finite number > 0"),
    ("scenario.dt=-0.02", r"scenario\.dt must be a finite number > 0"),
    ("scenario.dt=0.0025", r"scenario\.dt must be a multiple of sim\.substep"),
    ("scenario.dt=5", r"at most 3600 s \(time limit\)"),
    ("scenario.max_steps=1000000000", r"scenario\.max_steps must be in \[1, 200000\]"),
    ("scenario.max_steps=0", r"scenario\.max_steps"),
    ("scenario.goal_tolerance=-1", r"scenario\.goal_tolerance"),
    ("scenario.goal_tolerance=nan", r"scenario\.goal_tolerance"),
    ("sim.substep=0", r"sim\.substep must be in \(0, 0\.1\]"),
    ("sim.substep=0.00001", r"at most 1000 physics substeps"),
    ("clutter.count=100000", r"clutter\.count must be in \[0, 1000\]"),
    ("clutter.radius=0", r"clutter\.radius"),
    ("clutter.low=[2,0,0]", r"clutter\.low/high"),
    ("seed=-1", r"seed must be"),
    ("settle_time=-1", r"settle_time"),
    ("recorder.flush_every=0", r"recorder\.flush_every"),
])
def test_a_value_out_of_range_is_refused(hydra_conf, override, match):
    with pytest.raises(ConfigError, match=match):
        schema.run_config(compose("sweep", overrides=[override]))


@pytest.mark.parametrize("override,match", [
    ("method.beta=-1", r"method\.beta"),
    ("method.damping=soft", r"method\.damping must be constant or matched"),
    ("method.fabric.goal_weight=-1", r"fabric\.goal_weight"),
    ("method.fabric.obstacle.energy_gain=0", r"energy_gain must be positive"),
    ("method.forcing.configuration_pull=sometimes", r"method\.forcing\.configuration_pull"),
    ("method.forcing.mode=sum", r"method\.forcing\.mode"),
])
def test_a_method_value_out_of_range_is_refused(hydra_conf, override, match):
    with pytest.raises(ConfigError, match=match):
        schema.run_config(compose("sweep", overrides=["method=cpm", override]))


@pytest.mark.parametrize("method", ["puma", "fpm", "cpm", "modulation_ik"])
def test_every_learned_method_checks_its_model_choice(hydra_conf, method):
    with pytest.raises(ConfigError, match=r"method\.model must be auto \| real \| shipped"):
        schema.run_config(compose("sweep", overrides=[f"method={method}", "method.model=best"]))


@pytest.mark.parametrize("damping", cpm.DAMPINGS)
def test_the_schema_accepts_every_damping_the_cpm_controller_accepts(hydra_conf, damping):
    run = schema.run_config(compose("sweep", overrides=["method=cpm", f"method.damping={damping}"]))
    assert run.method.damping == damping


@pytest.mark.parametrize("override,match", [
    ("puma.train.iterations=0", r"puma\.train\.iterations must be a finite number > 0"),
    ("puma.train.iterations=100000000", r"at most 1000000"),
    ("puma.train.lr=-1", r"puma\.train\.lr"),
    ("puma.train.persist=2", r"puma\.train\.persist must be a finite number in \[0, 1\]"),
    ("puma.train.fresh_starts=-4",
     r"puma\.train\.fresh_starts must be a finite number >= 0, got -4"),
    ("puma.network.width=0", r"puma\.network\.width"),
    ("puma.eval.horizon=0", r"puma\.eval\.horizon"),
    ("puma.order=3", r"puma\.order must be 1 or 2"),
    ("puma.dt=0", r"puma\.dt"),
    ("+puma.train.iteration=10", r"puma\.train\.iteration: unknown key"),
])
def test_a_training_value_out_of_range_is_refused(hydra_conf, override, match):
    with pytest.raises(ConfigError, match=match):
        schema.train_config(compose("train", overrides=[override]))


@pytest.mark.parametrize("config,override", [("sweep", "scenario.dt=abc"),
                                             ("train", "puma.train.lr=abc"),
                                             ("sweep", "method.fabric.goal_weight=abc")])
def test_a_wrong_type_is_refused_at_composition(hydra_conf, config, override):
    """The schema heads each defaults list, so Hydra itself refuses a wrong type."""
    from hydra.errors import HydraException

    with pytest.raises((ConfigError, HydraException), match=re.escape(override.split("=")[0])):
        cfg = compose(config, overrides=[override])
        (schema.run_config if config == "sweep" else schema.train_config)(cfg)


def test_defaults_are_typed_objects_and_complete(hydra_conf):
    run = schema.run_config(compose("sweep", overrides=["method=cpm_literal"]))
    assert run.method.damping == "constant" and run.method.label == "cpm_literal"
    plain = schema.as_dict(run.method)
    assert {"beta", "variant", "control_rate", "pinv_damping",
            "checkpoint", "null_space", "fabric"} <= set(plain)
    from tamedpuma.worlds.bullet import SimConfig

    assert isinstance(run.sim, SimConfig)


_DEFAULTED_GET = re.compile(
    r"\b(\w*cfg|\w*conf|task|puma|syn|ws|clutter|robot|opts|method)\.get\(\s*['\"]\w+['\"]\s*,")




def test_no_library_default_besides_the_schema():
    """Library code reads complete configs. (analysis/ reads the configs stored in old logs,
    where a missing key means the run predates it: its fallbacks are not config defaults.)"""
    offenders = []
    for path in PKG.rglob("*.py"):
        if path.name == "schema.py" or path.relative_to(PKG).parts[0] == "analysis":
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if _DEFAULTED_GET.search(line):
                offenders.append(f"{path.relative_to(PKG)}:{n}: {line.strip()}")
    assert not offenders, "config defaults belong in app/schema.py:\n" + "\n".join(offenders)


def test_run_config_types_equal_sections_once_and_hands_out_copies(hydra_conf, monkeypatch):
    """The jobs of a sweep repeat their method and scenario sections: each is typed once per
    process (schema._TYPED), every call gets an equal object of its own (setting a field of one
    does not reach the next), and a bad value fails on every call, not only the first."""
    monkeypatch.setattr(schema, "_TYPED", {})
    calls = []
    real = schema.typed
    monkeypatch.setattr(schema, "typed", lambda *a, **k: calls.append(a[0]) or real(*a, **k))
    cfg = compose("sweep", ["method=fpm", "+case=tomato_03"])
    first, second = schema.run_config(cfg), schema.run_config(cfg)
    assert first == second and first is not second and first.method is not second.method
    sections, _ = schema._split_schema(schema.RunConfig)
    typed_once = 1 + len(sections) + 1  # the method, each section and the other values
    assert len(calls) == typed_once
    first.scenario.max_steps = 7  # a caller's own object
    third = schema.run_config(cfg)
    assert third == second and third.scenario.max_steps == second.scenario.max_steps != 7
    other = schema.run_config(compose("sweep", ["method=cpm", "+case=tomato_03"]))
    assert other.method.name == "cpm" and len(calls) == typed_once + 1  # the rest is known
    bad = compose("sweep", ["method=fpm", "+case=tomato_03", "scenario.max_steps=-1"])
    for _ in range(2):
        with pytest.raises(ConfigError, match="max_steps"):
            schema.run_config(bad)

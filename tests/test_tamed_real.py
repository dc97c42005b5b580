"""FPM and CPM on the default scenarios with trained models:
always with the shipped models (trained on the seeded synthetic demonstrations), and with the
real-data models where they are at hand (built by `python -m tamedpuma.models build` or trained
into runs/puma/, docs/data.md); skipped with a reason when there is none."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import real_model

from tamedpuma.analysis.path_difference import path_difference
from tamedpuma.app.config import load_group, start_options, typed_scenario
from tamedpuma.episode import run_episode
from tamedpuma.methods import make
from tamedpuma.worlds.bullet import Simulator
from tamedpuma.worlds.scenarios import scenario_from_config


class _PsiSpy:
    """Wraps a controller and keeps the ψ it logs at every step."""

    def __init__(self, controller):
        self.controller, self.psi = controller, []

    def reset(self, scenario):
        self.psi = []
        self.controller.reset(scenario)

    def step(self, obs):
        command = self.controller.step(obs)
        self.psi.append(command.scalars.get("psi", np.nan))
        return command


def _choice(task, model) -> str:
    """The override selecting the model: the shipped one, or the real-data one the tests run
    with (:func:`conftest.real_model`), skipped where there is none."""
    if model == "shipped":
        return "method.model=shipped"
    path = real_model(task)
    if path is None:
        pytest.skip(f"no real-data {task} model here (`python -m tamedpuma.models build` needs "
                    "the authors' demonstrations, or set TAMEDPUMA_MODELS; CI runs this with the "
                    "shipped models)")
    return f"method.checkpoint={path}"


def _method_cfg(name, task, choice):
    from tamedpuma.app.schema import method_settings, run_config
    from tamedpuma.app.train import compose

    cfg = compose("sweep", [f"method={name}", f"task={task}", choice])
    return method_settings(run_config(cfg).method)


def _scenario(spec, task, obstacles):
    cfg = load_group("scenario", "default")
    t = load_group("task", task)
    cfg["goal"].update(position=t["goal_position"], quaternion=t["goal_quaternion"])
    if not obstacles:
        cfg["obstacles"] = []
    return scenario_from_config(typed_scenario(cfg), spec, task=task, **start_options())


CASES = [("tomato", "shipped"),
         ("tomato", "real"),  # needs fabric.obstacle_activation: without it FPM rests 0.49 m
                              # short behind the obstacle (model 2cb8ca976ad6)
         ("pouring", "real"),
         ("pouring", "shipped")]



@pytest.mark.parametrize("task,model", CASES)
def test_fpm_and_cpm_follow_puma_and_avoid_on_the_default_scenarios(task, model, robot_spec,
                                                                     kinematics):
    choice = _choice(task, model)
    paths = {}
    for name in ("puma", "fpm", "cpm"):
        controller = _PsiSpy(make(name, _method_cfg(name, task, choice), kinematics))
        with Simulator(robot_spec) as sim:
            free = run_episode(_scenario(robot_spec, task, False), controller, sim)
        paths[name] = free.ee_position
        if name == "puma":
            # PUMA alone has no joint-limit or ground avoidance: where its own path runs into a
            # limit or the table (the shipped tomato model can end its approach 3.5 cm lower
            # than the goal, its links on the table) FPM and CPM must still reach the
            # goal, on another path, and there is no PUMA path to follow
            puma_feasible = free.metrics.success_whole_body
            assert free.metrics.success_paper or (model == "shipped"
                                                  and free.metrics.joint_limit_violation_steps > 0)
            continue
        assert free.metrics.success
        if name == "cpm":  # without obstacles ψ (almost) never rises
            psi = np.asarray(controller.psi)
            assert np.all(np.isfinite(psi)) and psi[-1] < 0.5 * psi[0]  # stopped 5 cm out
            # 1e-3 ψ₀: the joint-limit barriers (their energy ×30 for FPM and CPM) bend the path
            # where PUMA's runs close to a limit, and ψ may climb there (3e-4 ψ₀ on the shipped
            # tomato model); without the path loss ψ climbs by 3e-3 ψ₀ on the pouring default run
            assert np.max(np.diff(psi)) <= 1e-3 * psi[0]
        if puma_feasible:  # the bound on the path difference to PUMA (jl ×30: 0.03 m on
            # the shipped pouring model, whose path passes close to joint 4's limit)
            assert path_difference(free.ee_position, paths["puma"]) <= 0.04
        with Simulator(robot_spec) as sim:
            run = run_episode(_scenario(robot_spec, task, True), controller, sim)
        m = run.metrics
        assert m.success and not m.collided and m.min_clearance_m > 0
        assert m.joint_limit_violation_steps == 0
        assert np.all(np.abs(run.q) <= robot_spec.q_max)


TABLE1 = [f"{task}/{i:02d}" for task in ("tomato", "pouring") for i in range(15)]


def _table1_free_run(method, scenario, choice):
    """One Table-1 scenario without obstacles, as the sweep builds it, with the model override
    ``choice``: (result, goal position)."""
    from omegaconf import OmegaConf

    from tamedpuma.app.sweep import build
    from tamedpuma.app.train import compose

    b = build(OmegaConf.create(compose("sweep", [
        f"task={scenario.split('/')[0]}", f"scenario={scenario}", f"method={method}", choice,
        "recorder=none", "without_obstacles=true"])))
    with Simulator(b.spec, b.sim_config) as sim:
        return run_episode(b.scenario, b.controller, sim), np.asarray(b.scenario.goal.position)


def test_fpm_follows_puma_on_table1_without_obstacles():
    """The 30 Table-1 scenarios without obstacles, real-data models. FPM reaches the goal (whole
    body) in every one. Where PUMA alone succeeds (whole body: its own path inside the joint
    limits and off the table) FPM's path lies within 0.04 m of PUMA's on average (the paper's
    metric: 0.02 ± 0.04 there; 0.017-0.027 m with six models, both training recipes, seeds
    0-2). Where PUMA's path runs into a joint limit (pouring 00, 05, 06: joint 2 from about
    1.5 s on, the simulator holding it there) there is no PUMA path to follow, and FPM's may
    differ by 0.2 m; but FPM's hand never goes farther from the goal than PUMA's does, by more
    than 0.05 m (measured at most 0.021 m on those six models; eq. 9 as written 0.8 m; the
    failure this guards, the forcing's weighted solve driving joint 2 into a limit, took the
    hand 1.2 m from the goal on pouring 05)."""
    choices = {task: _choice(task, "real") for task in ("tomato", "pouring")}
    followed, detours, failed = [], {}, []
    for scenario in TABLE1:
        choice = choices[scenario.split("/")[0]]
        puma, goal = _table1_free_run("puma", scenario, choice)
        fpm, _ = _table1_free_run("fpm", scenario, choice)
        if not fpm.metrics.success:
            failed.append(scenario)
        if puma.metrics.success:
            followed.append(path_difference(fpm.ee_position, puma.ee_position))
        farthest = [np.max(np.linalg.norm(r.ee_position - goal, axis=1)) for r in (fpm, puma)]
        detours[scenario] = farthest[0] - farthest[1]
    assert not failed
    assert len(followed) >= 10 and np.mean(followed) <= 0.04
    assert max(detours.values()) <= 0.05, max(detours.items(), key=lambda kv: kv[1])

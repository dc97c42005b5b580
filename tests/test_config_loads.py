"""The cores launcher's shared config reads (tamedpuma/app/config_loads.py): every job's config is
the one Hydra composes without them, and a process reads each config file once."""

from __future__ import annotations

from hydra.core.global_hydra import GlobalHydra
from hydra.types import RunMode
from omegaconf import OmegaConf

from tamedpuma.app import config_loads
from tamedpuma.app.compose import session

#: jobs of different groups and values: task, case, method, experiment, an added key
JOBS = [["+case=tomato_03", "method=fpm"],
        ["+case=pouring_04", "method=cpm", "without_obstacles=true"],
        ["task=pouring", "method=modulation_ik", "seed=7"],
        ["+experiment=random", "method=fabrics", "scenario.goal_tolerance=0.03"],
        ["+case=tomato_03", "method=fpm"]]


def _composed(loader) -> list[str]:
    return [OmegaConf.to_yaml(loader.load_configuration("sweep", job, RunMode.MULTIRUN))
            for job in JOBS]


def test_shared_reads_compose_every_job_as_hydra_does_and_read_each_file_once(monkeypatch):
    monkeypatch.setattr(config_loads, "_LOADED", {})
    with session():
        loader = GlobalHydra.instance().config_loader()
        plain = _composed(loader)
        reads = []
        inner_load = type(loader.repository).load_config

        def counted(self, config_path):
            reads.append(config_path)
            return inner_load(self, config_path)

        monkeypatch.setattr(type(loader.repository), "load_config", counted)
        config_loads.share_loads(loader)
        config_loads.share_loads(loader)  # idempotent: one layer
        assert not isinstance(loader.repository._inner, config_loads.SharedLoads)
        first = _composed(loader)
        n_first = len(reads)
        again = _composed(loader)
    assert first == plain and again == plain
    assert n_first == len(set(reads)) > 10  # each file read once ...
    assert len(reads) == n_first  # ... and never again


def test_a_pickled_loader_reads_through_the_table_of_the_process_that_unpickles_it(monkeypatch):
    """The launcher sends each job a pickled copy of the loader: in a worker it fills and reuses
    that worker's table (:data:`config_loads._LOADED`), not a copy of the parent's made when it
    was pickled."""
    import cloudpickle  # as the launcher (joblib, loky) sends it

    monkeypatch.setattr(config_loads, "_LOADED", {})
    with session():
        loader = GlobalHydra.instance().config_loader()
        config_loads.share_loads(loader)
        expected = OmegaConf.to_yaml(loader.load_configuration("sweep", JOBS[0], RunMode.MULTIRUN))
        copy = cloudpickle.loads(cloudpickle.dumps(loader))
        monkeypatch.setattr(config_loads, "_LOADED", {})  # a fresh worker's empty table
        got = OmegaConf.to_yaml(copy.load_configuration("sweep", JOBS[0], RunMode.MULTIRUN))
        filled = dict(config_loads._LOADED)
        copy.load_configuration("sweep", JOBS[0], RunMode.MULTIRUN)
    assert isinstance(copy.repository, config_loads.SharedLoads) and got == expected
    assert type(copy) is config_loads.SweepConfigLoader  # composes jobs from its own process's
    assert len(filled) > 10  # the copy read into this process's table ...
    assert config_loads._LOADED.keys() == filled.keys()  # ... and then answered from it
    assert all(config_loads._LOADED[k] is v for k, v in filled.items())


def test_the_cores_launcher_shares_the_reads_of_the_loader_its_jobs_compose_with():
    from hydra.core.plugins import Plugins
    from hydra.types import HydraContext

    from tamedpuma.app.compose import compose

    cfg = compose("sweep", ["hydra/launcher=cores"], hydra_config=True)
    assert cfg.hydra.launcher._target_ == "hydra_plugins.tamedpuma_launcher.launcher.CoresLauncher"
    with session():
        loader = GlobalHydra.instance().config_loader()
        context = HydraContext(config_loader=loader, callbacks=None)
        launcher = Plugins.instance().instantiate_launcher(
            hydra_context=context, task_function=print, config=cfg)
        assert type(launcher).__mro__[1].__name__ == "JoblibLauncher"
        assert isinstance(loader.repository, config_loads.SharedLoads)
        assert type(loader) is config_loads.SweepConfigLoader
        assert launcher.joblib["n_jobs"] == -1 and str(launcher.joblib["batch_size"]) == "2"


def test_everything_but_the_reads_is_the_inner_repositorys():
    from hydra.core.object_type import ObjectType

    with session():
        repo = GlobalHydra.instance().config_loader().repository
        shared = config_loads.SharedLoads(repo)
        for group, kind in (("method", ObjectType.CONFIG), ("scenario", None),
                            ("", ObjectType.GROUP)):
            assert shared.get_group_options(group, kind) == repo.get_group_options(group, kind)
        assert shared.get_group_options("task") == repo.get_group_options("task")
        assert shared.group_exists("method") and not shared.group_exists("nothing")
        assert shared.config_exists("method/fpm") and not shared.config_exists("method/none")
        assert shared.get_sources() == repo.get_sources()
        assert shared.load_config("method/none") is None


def test_a_copy_of_the_shared_repository_is_independent_of_the_original():
    """Hydra's per-compose cache deep-copies the repository and re-initialises the copy's
    sources (a job's ``hydra.searchpath``); the shallow copy leaves the original's alone."""
    import copy

    from hydra._internal.config_repository import ConfigRepository
    from hydra._internal.config_search_path_impl import ConfigSearchPathImpl

    with session():
        shared = GlobalHydra.instance().config_loader().repository
        shared = shared if isinstance(shared, config_loads.SharedLoads) else \
            config_loads.SharedLoads(shared)
        assert type(shared._inner) is ConfigRepository
        before = [(s.provider, s.path) for s in shared.get_sources()]
        twin = copy.deepcopy(shared)
        assert twin._inner is not shared._inner
        twin.initialize_sources(ConfigSearchPathImpl())  # an empty search path
        assert twin.get_sources() == [] and len(before) > 1
        assert [(s.provider, s.path) for s in shared.get_sources()] == before
        assert shared.load_config("method/fpm") is not None


def test_a_cores_worker_keeps_its_plugin_registry_from_one_job_to_the_next(monkeypatch):
    """The launcher's execute_job hands Hydra's set_state the registry the worker already has
    (Hydra's would otherwise discover every plugin again), and nothing else of the state."""
    from hydra.core.plugins import Plugins
    from hydra.core.singleton import Singleton

    from hydra_plugins.tamedpuma_launcher import launcher

    registry = Plugins.instance()
    sent = {"instances": {"other": 1}, "omegaconf_resolvers": {}}
    assert launcher.with_known_plugins(sent)["instances"] == {"other": 1, Plugins: registry}
    assert sent == {"instances": {"other": 1}, "omegaconf_resolvers": {}}  # not written
    monkeypatch.setattr(Singleton, "_instances", {})  # a fresh worker: Hydra discovers them
    assert launcher.with_known_plugins(sent)["instances"] == {"other": 1}


# --- the composed selections: a job's plain values applied to its structural selection composed
# once (SweepConfigLoader.load_sweep_config) ------------------------------------------------------

#: (the sweep's command line, its jobs' overrides) as the real experiments sweep them; the
#: master's Hydra overrides reach every job (``hydra.overrides.hydra``)
SWEEPS = {
    "table1": (["+experiment=table1", "case=tomato_03,pouring_05", "method=fpm,cpm",
                "without_obstacles=false,true", "hydra.sweep.dir=/tmp/table1"],
               [["+experiment=table1", "case=tomato_03", "method=fpm", "without_obstacles=true"],
                ["+experiment=table1", "case=tomato_03", "method=fpm", "without_obstacles=false"],
                ["+experiment=table1", "case=pouring_05", "method=cpm", "without_obstacles=true"]]),
    "random": (["+experiment=random", "scenario.max_steps=1", "recorder=none",
                "hydra.job.config.override_dirname.exclude_keys=[scenario.random_seed]",
                "hydra.job.env_copy=[HOME]"],
               [["+experiment=random", "scenario.max_steps=1", "recorder=none", "task=pouring",
                 "method=cpm", "scenario.start_kind=anywhere", "scenario.random_seed=2051",
                 "without_obstacles=false"],
                ["+experiment=random", "scenario.max_steps=1", "recorder=none", "task=pouring",
                 "method=cpm", "scenario.start_kind=near_table1", "scenario.random_seed=2000",
                 "without_obstacles=true"]]),
    "ablation": (["+experiment=ablation_random"],
                 [["+experiment=ablation_random", "ablation=fpm/stall_pull", "task=tomato",
                   "scenario.start_kind=near_table1", "scenario.random_seed=2000"],
                  ["+experiment=ablation_random", "ablation=cpm/none", "task=pouring",
                   "scenario.start_kind=anywhere", "scenario.random_seed=2099"]]),
    "values": (["method=cpm"],
               [["method=cpm", "seed=7"],  # int
                ["method=cpm", "scenario.goal_tolerance=0.03", "settle_time=3.5"],  # float
                ["method=cpm", "stop_on_success=false", "without_obstacles=true"],  # bool
                ["method=cpm", "clutter.total=null"],  # null
                ["method=cpm", "clutter.low=[-1.0,-1.0,0.1]"],  # list
                ["method=cpm", "output_root=/tmp/elsewhere", "suite.name='a b'"],  # string
                ["method=cpm", "clutter={count: 2, radius: 0.04}"],  # dict into a node
                ["method=cpm", "output_root=${oc.env:HOME}/runs"],  # an interpolation
                ["method=cpm", "method.fabric.kernel=numpy", "sim=direct"]]),
}

#: overrides Hydra composes in full: an added key, a forced one, a deleted one
FALL_BACK = [["method=cpm", "+new_key=1", "seed=2"], ["method=cpm", "++seed=3"],
             ["method=cpm", "~seed", "settle_time=3.0"]]


def _fields(node, path="") -> list:
    """Every node of ``node`` with what OmegaConf keeps of it besides its value: its class,
    reference and object type, optionality and flags (struct, readonly, ...)."""
    from omegaconf import DictConfig, ListConfig

    meta = node._metadata
    rows = [(path, type(node).__name__, str(meta.ref_type), str(meta.object_type),
             meta.optional, sorted(meta.flags.items()), node._is_missing(), node._is_none())]
    if isinstance(node, DictConfig) and not (node._is_missing() or node._is_none()):
        for key in node.keys():
            rows += _fields(node._get_node(key), f"{path}.{key}")
    elif isinstance(node, ListConfig) and not (node._is_missing() or node._is_none()):
        for i in range(len(node)):
            rows += _fields(node._get_node(i), f"{path}[{i}]")
    return rows


def _same(cached, hydras) -> None:
    assert OmegaConf.to_yaml(cached, resolve=False) == OmegaConf.to_yaml(hydras, resolve=False)
    assert _fields(cached) == _fields(hydras)
    assert OmegaConf.get_cache(cached) == OmegaConf.get_cache(hydras)


def _sweep_configs(loader, sweeps) -> dict:
    """name -> (master config, [each job's config as ``loader.load_sweep_config`` gives it])"""
    out = {}
    for name, (command, jobs) in sweeps.items():
        master = loader.load_configuration("sweep", command, RunMode.MULTIRUN)
        OmegaConf.get_cache(master)["now"]["%H"] = "12"  # what a resolved ${now:} left
        out[name] = (master, [loader.load_sweep_config(master, job) for job in jobs])
    return out


def _spy_fast_path(monkeypatch) -> list:
    """The results of SweepConfigLoader's fast path (None: Hydra composed the job in full)."""
    seen = []
    fast = config_loads.SweepConfigLoader._from_composed

    def spied(self, master_config, sweep_overrides):
        seen.append(fast(self, master_config, sweep_overrides))
        return seen[-1]

    monkeypatch.setattr(config_loads.SweepConfigLoader, "_from_composed", spied)
    return seen


def _fresh_tables(monkeypatch) -> None:
    for table in ("_LOADED", "_COMPOSED", "_GROUPS"):
        monkeypatch.setattr(config_loads, table, {})


def test_composed_selections_give_every_experiment_job_hydras_config_field_for_field(monkeypatch):
    _fresh_tables(monkeypatch)
    with session():
        loader = GlobalHydra.instance().config_loader()
        hydras = _sweep_configs(loader, SWEEPS)
        config_loads.share_loads(loader)
        assert type(loader) is config_loads.SweepConfigLoader
        seen = _spy_fast_path(monkeypatch)
        cached = {}
        for name, (_, jobs) in SWEEPS.items():
            cached[name] = [loader.load_sweep_config(hydras[name][0], job) for job in jobs]
    assert all(cfg is not None for cfg in seen)  # every job took the fast path
    for name in SWEEPS:
        for got, expected in zip(cached[name], hydras[name][1], strict=True):
            _same(got, expected)
    # one compose per structural selection: table1 2, random 1, ablation 2, values 2 (sim=)
    assert len(config_loads._COMPOSED) == 7
    assert cached["random"][0].hydra.job.override_dirname == (
        "+experiment=random,method=cpm,recorder=none,scenario.max_steps=1,"
        "scenario.start_kind=anywhere,task=pouring,without_obstacles=false")
    assert list(cached["table1"][0].hydra.overrides.hydra) == ["hydra.sweep.dir=/tmp/table1"]


def test_jobs_of_one_selection_get_their_own_values_also_after_one_was_mutated(monkeypatch):
    _fresh_tables(monkeypatch)
    master_command, jobs = SWEEPS["random"]
    other = [*jobs[0][:-3], "scenario.start_kind=near_table1", "scenario.random_seed=2000",
             "without_obstacles=true"]
    with session():
        loader = GlobalHydra.instance().config_loader()
        master = loader.load_configuration("sweep", master_command, RunMode.MULTIRUN)
        first_hydra = loader.load_sweep_config(master, jobs[0])
        other_hydra = loader.load_sweep_config(master, other)
        config_loads.share_loads(loader)
        first = loader.load_sweep_config(master, jobs[0])
        first.scenario.random_seed = 1
        first.method.name = "mutated"
        first.clutter.low[0] = 9.0
        first.hydra.overrides.task.append("mutated=1")
        first.hydra.runtime.choices.method = "mutated"
        got = loader.load_sweep_config(master, other)
        again = loader.load_sweep_config(master, jobs[0])
    _same(got, other_hydra)
    _same(again, first_hydra)
    assert (got.scenario.random_seed, got.scenario.start_kind, got.without_obstacles) == (
        2000, "near_table1", True)
    assert len(config_loads._COMPOSED) == 1


def test_added_forced_and_deleted_keys_are_composed_by_hydra_in_full(monkeypatch):
    _fresh_tables(monkeypatch)
    with session():
        loader = GlobalHydra.instance().config_loader()
        master = loader.load_configuration("sweep", ["method=cpm"], RunMode.MULTIRUN)
        hydras = [loader.load_sweep_config(master, job) for job in FALL_BACK]
        config_loads.share_loads(loader)
        seen = _spy_fast_path(monkeypatch)
        cached = [loader.load_sweep_config(master, job) for job in FALL_BACK]
    assert seen == [None] * len(FALL_BACK) and not config_loads._COMPOSED
    for got, expected in zip(cached, hydras, strict=True):
        _same(got, expected)
    assert cached[0].new_key == 1 and cached[1].seed == 3 and "seed" not in cached[2]


def test_a_misspelt_or_unknown_override_fails_as_it_does_in_hydra(monkeypatch):
    _fresh_tables(monkeypatch)
    bad = [["+experiment=random", "task=pouring", "scenario.max_stepz=3"],
           ["+experiment=random", "method=nomethod", "seed=1"],
           ["+experiment=random", "seed=one"],
           ["+experiment=random", "seed=[1,2"],
           ["+experiment=random", "seed=1,2"]]

    def failure(loader, master, job):
        try:
            loader.load_sweep_config(master, job)
        except Exception as exc:
            return type(exc), str(exc), type(exc.__cause__), str(exc.__cause__)
        raise AssertionError(f"{job} composed")

    with session():
        loader = GlobalHydra.instance().config_loader()
        master = loader.load_configuration("sweep", ["+experiment=random"], RunMode.MULTIRUN)
        hydras = [failure(loader, master, job) for job in bad]
        config_loads.share_loads(loader)
        cached = [failure(loader, master, job) for job in bad]
        cached_again = [failure(loader, master, job) for job in bad]  # a selection composed
    assert cached == hydras and cached_again == hydras
    assert "scenario.max_stepz" in hydras[0][1]


def test_a_group_from_a_search_path_folder_is_a_structural_selection(monkeypatch, tmp_path):
    """The groups of a ``hydra.searchpath`` folder count as groups (an override of one is never
    taken for a plain value)."""
    (tmp_path / "extra").mkdir()
    (tmp_path / "extra" / "a.yaml").write_text("# @package _global_\nsettle_time: 4.0\n")
    _fresh_tables(monkeypatch)
    command = ["method=cpm", f"hydra.searchpath=[file://{tmp_path}]"]
    jobs = [["method=cpm", "+extra=a", "seed=5"], ["method=cpm", "+extra=a", "seed=6"]]
    with session():
        loader = GlobalHydra.instance().config_loader()
        master = loader.load_configuration("sweep", command, RunMode.MULTIRUN)
        hydras = [loader.load_sweep_config(master, job) for job in jobs]
        config_loads.share_loads(loader)
        seen = _spy_fast_path(monkeypatch)
        cached = [loader.load_sweep_config(master, job) for job in jobs]
    assert all(cfg is not None for cfg in seen) and len(config_loads._COMPOSED) == 1
    for got, expected in zip(cached, hydras, strict=True):
        _same(got, expected)
    assert cached[0].settle_time == 4.0 and [c.seed for c in cached] == [5, 6]


def test_what_hydra_takes_from_the_process_is_each_jobs_own(monkeypatch, tmp_path):
    """The working directory, an ``env_copy`` variable, the job name and the master's resolver
    cache are read at each job, as Hydra reads them, not kept from the first job of a
    selection."""
    from hydra.core.utils import JobRuntime

    _fresh_tables(monkeypatch)
    command = ["method=cpm", "hydra.job.env_copy=[TAMEDPUMA_TEST_ENV]"]
    job = ["method=cpm", "seed=3"]
    states = [("a", tmp_path, "app", "12"), ("b", tmp_path.parent, "app", "13"),
              ("c", tmp_path, "other", "14")]

    def configs(loader):
        out = []
        for (env, cwd, name, _), master in zip(states, masters, strict=True):
            monkeypatch.setenv("TAMEDPUMA_TEST_ENV", env)
            monkeypatch.chdir(cwd)
            JobRuntime().set("name", name)
            out.append(loader.load_sweep_config(master, job))
        return out

    monkeypatch.setenv("TAMEDPUMA_TEST_ENV", "master")
    job_name = JobRuntime().get("name")
    with session():
        loader = GlobalHydra.instance().config_loader()
        masters = [loader.load_configuration("sweep", command, RunMode.MULTIRUN) for _ in states]
        for master, (*_, hour) in zip(masters, states, strict=True):
            OmegaConf.get_cache(master)["now"]["%H"] = hour
        try:
            hydras = configs(loader)
            config_loads.share_loads(loader)
            cached = configs(loader)
        finally:
            JobRuntime().set("name", job_name)
    for got, expected in zip(cached, hydras, strict=True):
        _same(got, expected)
    assert [(c.hydra.job.env_set.TAMEDPUMA_TEST_ENV, c.hydra.runtime.cwd, c.hydra.job.name)
            for c in cached] == [(e, str(d), n) for e, d, n, _ in states]
    assert [OmegaConf.get_cache(c)["now"]["%H"] for c in cached] == ["12", "13", "14"]
    assert len(config_loads._COMPOSED) == 2  # one per job name


def test_overrides_are_classified_as_plain_values_structural_or_hydras_to_compose():
    """Plain: a changed value of a key that is no group (nor with dots as slashes); structural:
    a group's selection; anything else (and a sweep): Hydra composes the job in full."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    cases = {"scenario.random_seed=2051": "plain", "without_obstacles=true": "plain",
             "scenario.start_kind=anywhere": "plain", "clutter={count: 2}": "plain",
             "output_root='a b'": "plain", "clutter.total=null": "plain",
             "method=fpm": "structural", "task=pouring": "structural",
             "+experiment=random": "structural", "ablation=fpm/stall_pull": "structural",
             "~disturbance": "structural", "method@other=fpm": "structural",
             "scenario.tomato=x": "full",  # scenario/tomato is a group
             "scenario=tomato/03": "structural", "+new_key=1": "full", "++seed=1": "full",
             "~seed": "full", "seed@pkg=1": "full", "method={name: x}": "full",
             "seed=1,2": "full", "method=fpm,cpm": "full", "++method=fpm": "full"}
    parsed = OverridesParser.create().parse_overrides(list(cases))
    with session():
        repo = GlobalHydra.instance().config_loader().repository
        is_group = repo.group_exists
        got = {o.input_line: ("plain" if config_loads._is_plain_value(o, is_group) else
                              "structural" if config_loads._is_group_selection(o, is_group) else
                              "full") for o in parsed}
    assert got == cases

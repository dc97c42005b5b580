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
        assert launcher.joblib["n_jobs"] == -1 and str(launcher.joblib["batch_size"]) == "1"


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

"""The ``cores`` launcher (``conf/hydra/launcher/cores.yaml``): Hydra's joblib launcher whose
workers read each config file, and compose each distinct selection of config groups, once per
process instead of once per job (:mod:`tamedpuma.app.config_loads`), keep Hydra's plugin
registry from one job to the next instead of discovering every plugin again for each job, write
a job's config files through libyaml and send no config back (:func:`execute_job`). It
lives in the ``hydra_plugins`` namespace because Hydra instantiates launchers from there only.

:func:`launch` and :func:`execute_job` follow ``hydra_plugins.hydra_joblib_launcher._core``
(Hydra's joblib launcher plugin, MIT licence, Copyright (c) Facebook, Inc. and its affiliates).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, configure_log, filter_overrides, setup_globals
from hydra_plugins.hydra_joblib_launcher import _core
from hydra_plugins.hydra_joblib_launcher.joblib_launcher import JoblibLauncher

from tamedpuma.app.config_loads import share_loads

log = logging.getLogger(__name__)


def execute_job(idx: int, overrides, hydra_context, config, task_function,
                singleton_state: dict[str, Any]) -> JobReturn:
    """Hydra's ``execute_job`` (compose the job, run it with ``run_job``), with three costs
    of Hydra's taken out, none of which changes a job's config, files or outcome:

    - the plugin registry this worker process found for an earlier job is put back into the
      job's singleton state (:func:`with_known_plugins`): Hydra leaves it out of the state it
      sends (it does not pickle) and ``Singleton.set_state`` discovers every plugin again
      (imports and scans the ``hydra_plugins`` packages, ~35 ms), for the same plugins;
    - the job's ``.hydra/*.yaml`` are written by :func:`tamedpuma.app.sweep.save_config_or_stop`
      (the same text through libyaml, :mod:`tamedpuma.app.config_text`; a full disk stops the
      sweep with one line, as in the launching process);
    - Hydra's ``set_config`` before ``run_job`` is left out (``run_job`` sets the same config
      first thing), and the job's configs are dropped from the ``JobReturn`` sent back to the
      launching process (its sweeper reads only the return value; pickling and reading the two
      configs back cost ~10 ms of CPU per job)."""
    import hydra.core.utils
    from hydra.core.utils import run_job
    from omegaconf import open_dict

    from tamedpuma.app.sweep import save_config_or_stop

    hydra.core.utils._save_config = save_config_or_stop
    setup_globals()
    Singleton.set_state(with_known_plugins(singleton_state))
    sweep_config = hydra_context.config_loader.load_sweep_config(config, list(overrides))
    with open_dict(sweep_config):
        sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{idx}"
        sweep_config.hydra.job.num = idx
    ret = run_job(hydra_context=hydra_context, config=sweep_config, task_function=task_function,
                  job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir")
    ret.cfg = ret.hydra_cfg = None
    return ret


def with_known_plugins(singleton_state: dict[str, Any]) -> dict[str, Any]:
    """``singleton_state`` (not written) with the plugin registry this process already has, if
    it has one."""
    from hydra.core.plugins import Plugins

    known = Singleton._instances.get(Plugins)
    if known is None:
        return singleton_state
    return {**singleton_state, "instances": {**singleton_state["instances"], Plugins: known}}


def launch(launcher: JoblibLauncher, job_overrides, initial_job_idx: int) -> list[JobReturn]:
    """Hydra's joblib ``launch``, dispatching :func:`execute_job`."""
    from joblib import Parallel, delayed

    setup_globals()
    configure_log(launcher.config.hydra.hydra_logging, launcher.config.hydra.verbose)
    sweep_dir = Path(str(launcher.config.hydra.sweep.dir))
    sweep_dir.mkdir(parents=True, exist_ok=True)
    joblib_cfg = launcher.joblib
    joblib_cfg["backend"] = "loky"  # Hydra's: its threading backend is incompatible with Hydra
    _core.process_joblib_cfg(joblib_cfg)
    log.info("Joblib.Parallel(%s) is launching %d jobs",
             ",".join(f"{k}={v}" for k, v in joblib_cfg.items()), len(job_overrides))
    log.info("Launching jobs, sweep output dir : %s", sweep_dir)
    for idx, overrides in enumerate(job_overrides):
        log.info("\t#%d : %s", idx, " ".join(filter_overrides(overrides)))
    singleton_state = Singleton.get_state()
    runs = Parallel(**joblib_cfg)(
        delayed(execute_job)(initial_job_idx + idx, overrides, launcher.hydra_context,
                             launcher.config, launcher.task_function, singleton_state)
        for idx, overrides in enumerate(job_overrides))
    assert all(isinstance(run, JobReturn) for run in runs)
    return list(runs)


class CoresLauncher(JoblibLauncher):
    """Hydra's joblib launcher (the same settings, processes and jobs) whose config loader, the
    one every job composes with, shares the config files a process has read and the selections
    it has composed, and whose workers keep Hydra's plugin registry across their jobs."""

    def setup(self, *, hydra_context, task_function, config) -> None:
        share_loads(hydra_context.config_loader)
        super().setup(hydra_context=hydra_context, task_function=task_function, config=config)

    def launch(self, job_overrides, initial_job_idx: int) -> list[JobReturn]:
        assert self.config is not None and self.task_function is not None
        assert self.hydra_context is not None
        return launch(self, job_overrides, initial_job_idx)

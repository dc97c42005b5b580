"""The ``cores`` launcher (``conf/hydra/launcher/cores.yaml``): Hydra's joblib launcher whose
workers read each config file, and compose each distinct selection of config groups, once per
process instead of once per job (:mod:`tamedpuma.app.config_loads`), and keep Hydra's plugin
registry from one job to the next instead of discovering every plugin again for each job. It
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
    """Hydra's ``execute_job`` (compose the job, run it), with the plugin registry this worker
    process found for an earlier job put back into the job's singleton state: Hydra leaves the
    registry out of the state it sends (it does not pickle) and ``Singleton.set_state``
    discovers every plugin again (imports and scans the ``hydra_plugins`` packages, ~35 ms),
    for the same installed plugins every time."""
    from hydra.core.plugins import Plugins

    known = Singleton._instances.get(Plugins)
    if known is not None:
        singleton_state = {**singleton_state,
                           "instances": {**singleton_state["instances"], Plugins: known}}
    return _core.execute_job(idx, overrides, hydra_context, config, task_function,
                             singleton_state)


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

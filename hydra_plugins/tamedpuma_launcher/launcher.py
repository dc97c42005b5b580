"""The ``cores`` launcher (``conf/hydra/launcher/cores.yaml``): Hydra's joblib launcher whose
workers read each config file, and compose each distinct selection of config groups, once per
process instead of once per job (:mod:`tamedpuma.app.config_loads`). It lives in the
``hydra_plugins`` namespace because Hydra instantiates launchers from there only.
"""

from __future__ import annotations

from hydra_plugins.hydra_joblib_launcher.joblib_launcher import JoblibLauncher

from tamedpuma.app.config_loads import share_loads


class CoresLauncher(JoblibLauncher):
    """Hydra's joblib launcher (the same settings, processes and jobs) whose config loader, the
    one every job composes with, shares the config files a process has read and the selections
    it has composed."""

    def setup(self, *, hydra_context, task_function, config) -> None:
        share_loads(hydra_context.config_loader)
        super().setup(hydra_context=hydra_context, task_function=task_function, config=config)

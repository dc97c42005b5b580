"""tamedpuma's ``cores`` launcher (``conf/hydra/launcher/cores.yaml``), where Hydra looks for
launchers: in the ``hydra_plugins`` namespace."""

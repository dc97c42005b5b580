"""A config's YAML text, as ``OmegaConf.to_yaml`` writes it, at a third of its cost.

Every job of a sweep writes its config three times (Hydra's ``.hydra/config.yaml``,
``hydra.yaml``, ``overrides.yaml``) and embeds it once more, resolved, in its MCAP log.
``OmegaConf.to_yaml`` dumps through PyYAML's pure-Python emitter: ~20 ms for a run's config
(~350 lines), as long as a thousand controller steps of the simulator. :func:`to_yaml` dumps the
same container with the same representers (OmegaConf's, which quote strings that would read back
as a bool, int or float) through libyaml's C emitter where PyYAML has it, else through
OmegaConf; the text is byte for byte OmegaConf's (``tests/test_config_text.py`` compares them on
every config of the shipped experiments).
"""

from __future__ import annotations

from pathlib import Path

import yaml
from omegaconf import OmegaConf


def _fast_dumper():
    """PyYAML's C dumper with OmegaConf's string representer (None without libyaml)."""
    if not getattr(yaml, "__with_libyaml__", False):
        return None
    from omegaconf._utils import OmegaConfDumper, get_omega_conf_dumper

    get_omega_conf_dumper()  # OmegaConf registers its str representer on first use

    class Dumper(yaml.CDumper):
        pass

    Dumper.add_representer(str, OmegaConfDumper.str_representer)
    return Dumper


_DUMPER = _fast_dumper()


def to_yaml(cfg, resolve: bool = False) -> str:
    """``OmegaConf.to_yaml(cfg, resolve=resolve)``: the same text (keys in their order)."""
    if _DUMPER is None:
        return OmegaConf.to_yaml(cfg, resolve=resolve)
    container = OmegaConf.to_container(cfg, resolve=resolve, enum_to_str=True)
    return yaml.dump(container, Dumper=_DUMPER, default_flow_style=False, allow_unicode=True,
                     sort_keys=False)


def save_config(cfg, filename: str, output_dir: Path) -> None:
    """Hydra's ``hydra.core.utils._save_config``: ``output_dir/filename`` holding
    :func:`to_yaml` of ``cfg`` (the folder made if missing)."""
    output_dir = Path(output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    (output_dir / filename).write_text(to_yaml(cfg), encoding="utf-8")

"""LASA benchmark: ``python -m tamedpuma.lasa [task.shapes=[Angle,GShape]] [overrides...]``.

Trains and evaluates a second-order 2-D PUMA on each LASA handwriting shape (all 30 by default)
and writes the table of mean RMSE, DTW and Fréchet distances and non-converging grid rollouts to
``benchmarks/lasa.md`` (and ``.json``); checkpoints go to ``runs/lasa/<shape>/``. Overrides are
Hydra's, on top of ``conf/train.yaml`` with ``task=lasa puma=lasa``. Errors: one line, exit 2.
"""

from __future__ import annotations

import sys

from tamedpuma.app.cli import command
from tamedpuma.app.compose import compose_dict


@command(__doc__)
def main(argv: list[str]) -> int:
    cfg = compose_dict("train", ["task=lasa", "puma=lasa", "out_dir=runs/lasa", "progress=false",
                                 "overwrite=true",  # the benchmark retrains every shape
                                 *argv])
    from tamedpuma.app import provenance
    from tamedpuma.puma import lasa_benchmark

    start = provenance.stamp(provenance.command_line("tamedpuma.lasa", argv))
    rows = lasa_benchmark.run(cfg, log=lambda m: print(m, file=sys.stderr),
                              stamp=lambda: provenance.with_end(start))
    print(lasa_benchmark.markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`python -m analysis.ablation RUNS`: a thin wrapper of :mod:`tamedpuma.analysis.ablation`."""

from tamedpuma.analysis.ablation import main

if __name__ == "__main__":
    raise SystemExit(main())

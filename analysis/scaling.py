"""`python -m analysis.scaling RUNS`: a thin wrapper of :mod:`tamedpuma.analysis.scaling`."""

from tamedpuma.analysis.scaling import main

if __name__ == "__main__":
    raise SystemExit(main())

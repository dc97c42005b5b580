"""`python -m analysis.tables RUNS`: a thin wrapper of :mod:`tamedpuma.analysis.tables`."""

from tamedpuma.analysis.tables import main

if __name__ == "__main__":
    raise SystemExit(main())

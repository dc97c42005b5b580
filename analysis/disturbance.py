"""`python -m analysis.disturbance RUNS`: a thin wrapper of
:mod:`tamedpuma.analysis.disturbance`."""

from tamedpuma.analysis.disturbance import main

if __name__ == "__main__":
    raise SystemExit(main())

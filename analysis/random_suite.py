"""`python -m analysis.random_suite RUNS`: a thin wrapper of
:mod:`tamedpuma.analysis.random_suite`."""

from tamedpuma.analysis.random_suite import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m analysis.report RUNS`: a thin wrapper of :mod:`tamedpuma.analysis.report`."""

from tamedpuma.analysis.report import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m analysis.figures RUNS`: a thin wrapper of :mod:`tamedpuma.analysis.figures`."""

from tamedpuma.analysis.figures import main

if __name__ == "__main__":
    raise SystemExit(main())

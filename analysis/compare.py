"""`python -m analysis.compare RUNS_A RUNS_B`: wraps :mod:`tamedpuma.analysis.compare`."""

from tamedpuma.analysis.compare import main

if __name__ == "__main__":
    raise SystemExit(main())

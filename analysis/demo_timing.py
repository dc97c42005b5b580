"""`python -m analysis.demo_timing DIR [DIR ...]`: a thin wrapper of
:mod:`tamedpuma.analysis.demo_timing`."""

from tamedpuma.analysis.demo_timing import main

if __name__ == "__main__":
    raise SystemExit(main())

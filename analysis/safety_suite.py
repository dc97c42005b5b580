"""`python -m analysis.safety_suite ...`: a thin wrapper of :mod:`tamedpuma.app.safety_suite`
(installed as `python -m tamedpuma.safety_suite` and `tamedpuma-safety-suite`)."""

from tamedpuma.analysis.safety import split_by_puma_limits, summarise  # noqa: F401
from tamedpuma.app.safety_suite import main, run_one  # noqa: F401

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tamedpuma.safety_suite`: entry point in :mod:`tamedpuma.app.safety_suite`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.safety_suite import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tamedpuma.recheck`: entry point in :mod:`tamedpuma.app.step_recheck`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.step_recheck import main

if __name__ == "__main__":
    raise SystemExit(main())

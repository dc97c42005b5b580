"""`python -m tamedpuma.sweep`: the entry point lives in :mod:`tamedpuma.app.sweep`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.sweep import main

if __name__ == "__main__":
    raise SystemExit(main())

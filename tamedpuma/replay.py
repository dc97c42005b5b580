"""`python -m tamedpuma.replay`: the entry point lives in :mod:`tamedpuma.app.replay`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.replay import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tamedpuma.train`: the entry point lives in :mod:`tamedpuma.app.train`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.train import main

if __name__ == "__main__":
    raise SystemExit(main())

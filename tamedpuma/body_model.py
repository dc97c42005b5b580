"""`python -m tamedpuma.body_model`: the entry point lives in :mod:`tamedpuma.app.body_model`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.body_model import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tamedpuma.models`: the entry point lives in :mod:`tamedpuma.app.models`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.models import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tamedpuma.lasa`: the entry point lives in :mod:`tamedpuma.app.lasa`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.lasa import main

if __name__ == "__main__":
    raise SystemExit(main())

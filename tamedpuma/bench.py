"""`python -m tamedpuma.bench`: entry point in :mod:`tamedpuma.app.bench`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.bench import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tamedpuma.sweep`: the entry point lives in :mod:`tamedpuma.app.sweep`."""

from tamedpuma.app.sweep import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tamedpuma.replay`: the entry point lives in :mod:`tamedpuma.app.replay`."""

from tamedpuma.app.replay import main

if __name__ == "__main__":
    raise SystemExit(main())

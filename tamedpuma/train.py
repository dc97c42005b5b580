"""`python -m tamedpuma.train`: the entry point lives in :mod:`tamedpuma.app.train`."""

from tamedpuma.app.train import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tamedpuma.body_model`: the entry point lives in :mod:`tamedpuma.app.body_model`."""

from tamedpuma.app.body_model import main

if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tamedpuma.bench`: entry point in :mod:`tamedpuma.app.bench`."""

from tamedpuma.app.bench import main

if __name__ == "__main__":
    raise SystemExit(main())

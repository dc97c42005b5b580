"""`python -m tamedpuma.ablation`: the entry point lives in :mod:`tamedpuma.app.ablation`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.ablation import main

if __name__ == "__main__":
    raise SystemExit(main())

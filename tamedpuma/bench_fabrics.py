"""`python -m tamedpuma.bench_fabrics`: entry point in :mod:`tamedpuma.app.bench_fabrics`."""

from tamedpuma.startup import starting

with starting():  # Ctrl-C or SIGTERM while loading: one line, no traceback
    from tamedpuma.app.bench_fabrics import main

if __name__ == "__main__":
    raise SystemExit(main())

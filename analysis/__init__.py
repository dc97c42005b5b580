"""Analysis: run logs (MCAP) -> pandas -> the paper's tables. Reads files, never live objects."""

"""Every figure the `manus` command draws, one module per subject; `common` holds the file-only
pyplot, saving, and the recording figure."""

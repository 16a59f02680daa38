"""fsync of a file or a directory, best effort: what every durable write of vcirun (the kernel cache,
results files, summaries) calls after writing a file and after renaming it into place."""
from __future__ import annotations

import os
from pathlib import Path


def fsync_path(path: Path, directory: bool = False) -> None:
    """fsync the file (or, with `directory`, the directory) at `path`; errors are ignored (a file
    system without fsync for directories, a path that went away: the write itself has succeeded)."""
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)

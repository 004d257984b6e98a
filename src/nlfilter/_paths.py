"""Where nlfilter keeps its files by default: ``$XDG_CACHE_HOME/nlfilter`` (``~/.cache`` when
``XDG_CACHE_HOME`` is unset) — the results store (:func:`nlfilter.store.default_path`) and,
beside it, the compiled loops (:func:`nlfilter.filters.compiled.cache.cache_root`)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["home"]


def home() -> Path:
    """``$XDG_CACHE_HOME/nlfilter``, default ``~/.cache/nlfilter``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "nlfilter"

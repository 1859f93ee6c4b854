"""Build helpers for setup.py (not installed): when an engine object must be recompiled."""
from __future__ import annotations

import os
from typing import Sequence


class HeaderAwareRecompile:
    """needs_recompile for pybind11's ParallelCompile: an object older than its .cpp or than any engine header.

    pybind11's naive_recompile compares an object with its own .cpp only, and ParallelCompile applies it even under
    --force; after a header change (a `git pull`, a branch switch) the objects of unchanged .cpp files that include it
    were linked as they were, beside recompiled ones: a struct whose layout changed then crashes the module. The
    engine's headers are few and shared, so any newer header recompiles every object (as a header change should).
    """

    def __init__(self, headers: Sequence[str]):
        self.headers = list(headers)

    def __call__(self, obj: str, src: str) -> bool:
        if not os.path.exists(obj):
            return True
        built = os.stat(obj).st_mtime
        return any(os.stat(path).st_mtime >= built for path in (src, *self.headers))

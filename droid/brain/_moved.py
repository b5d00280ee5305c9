"""The old module paths that droid.brain keeps after its split into subpackages (issue 43 item 5).

A device package outside the repository imports a few Brain modules (docs/architecture.md
"Adding a device class"); each of those old paths is a module of its own beside the
subpackages that hands on the moved module's public names and warns, through this.  Nothing
inside ``droid`` imports through them (tests/brain/test_moved_paths.py).
"""
from __future__ import annotations

import warnings


def warn_moved(old: str, new: str) -> None:
    """One DeprecationWarning naming the new path, pointed past the import machinery at the importer."""
    warnings.warn(f"{old} is deprecated: it moved to {new}; import that", DeprecationWarning, stacklevel=3)

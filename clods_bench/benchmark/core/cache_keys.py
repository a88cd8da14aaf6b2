"""Keys of the on-disk caches (fitted simulators and predictors, CloDS stages 1-2): 16 hex digits of a JSON identity.

Fits made on the host's own floating-point paths (`--no-deterministic`) get other keys than deterministic ones, so
the two never share a cache entry.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

from clods_bench import numerics

CACHE_FORMAT = 1


def digest(identity: Any) -> str:
    """16 hex digits of the SHA-256 of a JSON-able identity (sorted keys)."""
    key: dict[str, Any] = {"format": CACHE_FORMAT, "identity": identity}
    if numerics.numeric_mode() != "deterministic":  # fits made on the host's own paths stay apart
        key["numeric_mode"] = numerics.numeric_mode()
    blob = json.dumps(key, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]

"""Which worker process serves which responder."""
from __future__ import annotations

import zlib
from functools import lru_cache

SHARD_KEYS_KEPT = 8192  # keys whose shard is remembered (the worker asks for every frame it hears)


@lru_cache(maxsize=SHARD_KEYS_KEPT)
def in_shard(key_or_id: str, k: int, n: int) -> bool:
    """Does the responder of this key (or id) belong to worker ``k`` of ``n``? A stable hash
    of the responder id (CRC-32), so every worker agrees without talking to the others."""
    parts = key_or_id.split("/")
    rid = parts[2] if len(parts) == 4 else key_or_id
    return zlib.crc32(rid.encode()) % n == k

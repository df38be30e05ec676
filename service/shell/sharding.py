"""Which worker process serves which responder."""
from __future__ import annotations

import zlib
from functools import lru_cache

SHARD_IDS_KEPT = 8192  # ids whose shard is remembered (the worker asks for every frame it hears)


@lru_cache(maxsize=SHARD_IDS_KEPT)
def in_shard(rid: str, k: int, n: int) -> bool:
    """Does responder ``rid`` belong to worker ``k`` of ``n``? A stable hash of the id (CRC-32),
    so every worker agrees without talking to the others. The shell reads a message's key once
    (:func:`service.protocol.keys.read_key`) and asks with the id it names; a message whose key
    is not one names nobody and is worker 0's (:func:`owns`)."""
    return zlib.crc32(rid.encode()) % n == k


def owns(parts, k: int, n: int) -> bool:
    """Does worker ``k`` of ``n`` take a message whose key read as ``parts``
    (:class:`service.protocol.keys.KeyParts`, or the ValueError of a key that is not one:
    worker 0 takes those, and its intake refuses them as ``bad_key``)?"""
    if n == 1:
        return True
    return k == 0 if isinstance(parts, ValueError) else in_shard(parts.responder, k, n)

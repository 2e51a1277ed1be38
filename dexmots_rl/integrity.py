"""Payload checksums of checkpoints and plans: sha256 over every value of a saved dict, in a fixed order.

``torch.load`` does not notice a flipped bit inside a tensor (the zip stores tensor bytes raw), so a
corrupt checkpoint or plan would load with silently wrong numbers. Both file formats store
:func:`payload_digest` of their payload under :data:`CHECKSUM_KEY` and verify it on load.

The digest covers keys, Python scalars (``repr``, exact for floats), and every tensor's dtype, shape
and raw bytes; mappings are walked in sorted-key order so the digest does not depend on insertion
order, and tensors are hashed from CPU memory so it does not depend on the device.

Example:
    >>> import torch
    >>> a = payload_digest({"w": torch.zeros(3), "step": 1})
    >>> a == payload_digest({"step": 1, "w": torch.zeros(3)})
    True
    >>> a == payload_digest({"w": torch.tensor([0.0, 0.0, 1e-45]), "step": 1})
    False
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from typing import Any

import torch

__all__ = ["CHECKSUM_KEY", "load_failure", "payload_digest", "with_checksum", "checksum_problem"]

CHECKSUM_KEY = "sha256"


def _feed(h, obj: Any) -> None:
    if isinstance(obj, torch.Tensor):
        t = obj.detach().to("cpu").contiguous()
        h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    elif isinstance(obj, Mapping):
        items = sorted(obj.items(), key=lambda kv: (type(kv[0]).__name__, repr(kv[0])))
        h.update(f"D{len(items)}".encode())
        for key, value in items:
            _feed(h, key)
            _feed(h, value)
    elif isinstance(obj, (list, tuple)):  # torch.load may turn one into the other: same digest
        h.update(f"L{len(obj)}".encode())
        for value in obj:
            _feed(h, value)
    else:  # None, bool, int, float, str, bytes, torch.dtype ...: repr is exact and type-tagged
        h.update(f"S{type(obj).__name__}:{obj!r};".encode())


def payload_digest(payload: Mapping[str, Any]) -> str:
    """Hex sha256 of ``payload`` without its :data:`CHECKSUM_KEY` entry."""
    h = hashlib.sha256()
    _feed(h, {k: v for k, v in payload.items() if k != CHECKSUM_KEY})
    return h.hexdigest()


def with_checksum(payload: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of ``payload`` with its digest stored under :data:`CHECKSUM_KEY`."""
    return {**payload, CHECKSUM_KEY: payload_digest(payload)}


def checksum_problem(payload: Mapping[str, Any]) -> str | None:
    """``None`` when the stored digest matches the payload, else what is wrong (for the caller's error)."""
    stored = payload.get(CHECKSUM_KEY)
    if not isinstance(stored, str):
        return f"has no {CHECKSUM_KEY} checksum"
    actual = payload_digest(payload)
    if stored != actual:
        return f"is corrupt: {CHECKSUM_KEY} checksum mismatch (stored {stored[:12]}..., contents hash to {actual[:12]}...)"
    return None


def load_failure(err: BaseException) -> str:
    """One line saying why ``torch.load`` could not read a file: the exception's type and its message's first
    sentence, at most 160 characters. On bytes that are no archive at all torch answers with paragraphs of advice
    on loading untrusted files with ``weights_only=False``, which is not what the user needs to hear."""
    lines = str(err).strip().splitlines()
    first = lines[0].split(". ")[0] if lines else ""  # its first sentence
    if first.startswith("Weights only load failed"):
        first = "not a torch file of tensors"
    return f"{type(err).__name__}: {first[:160]}"

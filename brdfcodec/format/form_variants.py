"""Form variants (``spec/bvae-format.md`` §3.2, since 2.7): a layered form written as an earlier form's index and
the fields in which it differs.

A library whose records choose their coded layer's prior, their μ grid or their first basis vector per material
has several layered forms that differ in one or two numbers; written in full each costs 9 bytes (a coded μ), as
a variant 4–5. Both the writer and the reader work on a form's bytes *written in full*: the writer compares them
to choose a variant's base, the reader rebuilds them from a variant and checks them as a full form.

Examples
--------
A coded-μ form on the grid 2^−3, and the same form on 2^−2 written as its variant (kind 3, base 0, the
``mu step`` bit, the new step):

>>> full = bytes([2, 4, 3, 9, 8, 50, 156, 28, 3])
>>> other = bytes([2, 4, 3, 9, 8, 50, 156, 28, 2])
>>> variant_bytes(other, 0, full).hex(" ")
'03 00 10 02'
>>> resolve_variant(full, {"mu_step": bytes([2])}) == other
True
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

__all__ = [
    "LAYERED_KIND",
    "RESERVED_CHANGE_BITS",
    "VARIANT_FIELDS",
    "VARIANT_FIELD_SIZES",
    "VARIANT_KIND",
    "best_variant",
    "resolve_variant",
    "split_layered_form",
    "variant_bytes",
]

#: Kind codes of a layered form and of a variant (§3.2).
LAYERED_KIND = 2
VARIANT_KIND = 3
#: The fields a variant may change, bit i of its ``changes`` byte naming field i, in the order a form lists them.
VARIANT_FIELDS = ("first", "project", "top", "prior", "mu_step", "detail")
#: Each variant field's size in bytes (0: a varint), as a form written in full stores it (§3.2).
VARIANT_FIELD_SIZES = {"first": 0, "project": 0, "top": 1, "prior": 2, "mu_step": 1, "detail": 1}
#: Bits of the ``changes`` byte no field is named by (unsupported when set).
RESERVED_CHANGE_BITS = 0xFF & ~((1 << len(VARIANT_FIELDS)) - 1)

_LAYER_BASIS, _LAYER_DETAIL, _LAYER_PACKED, _LAYER_CODED = 1, 2, 4, 8
_MU_CODED = 4


def _varint_length(data: bytes, at: int) -> int:
    """Bytes of the LEB128 varint starting at ``data[at]`` (a well-formed one)."""
    end = at
    while data[end] & 0x80:
        end += 1
    return end + 1 - at


def split_layered_form(full: bytes) -> tuple[bytes, dict[str, bytes]]:
    """A layered form's bytes written in full, split into its head (kind, ``mu``, ``sigma``, ``layers``: the
    layout every variant of it keeps) and its fields' bytes by name, in :data:`VARIANT_FIELDS` order.

    ``full`` must be a well-formed layered form (the writer's bytes, or bytes the reader has checked): nothing
    after its last field.
    """
    if len(full) < 4 or full[0] != LAYERED_KIND:
        raise ValueError("not the bytes of a layered form")
    head, mu, bits, at = full[:4], full[1], full[3], 4
    fields: dict[str, bytes] = {}

    def take(name: str) -> None:
        nonlocal at
        size = VARIANT_FIELD_SIZES[name] or _varint_length(full, at)
        fields[name] = full[at : at + size]
        at += size

    if bits & _LAYER_BASIS:
        take("first")
        take("project")
        if bits & _LAYER_PACKED:
            take("top")
        if bits & _LAYER_CODED:
            take("prior")
            if mu == _MU_CODED:
                take("mu_step")
    if bits & _LAYER_DETAIL:
        take("detail")
    if at != len(full):
        raise ValueError("bytes after the layered form's last field")
    return head, fields


def resolve_variant(base_full: bytes, changes: Mapping[str, bytes]) -> bytes:
    """The form a variant makes, written in full: ``base_full`` (a layered form written in full) with the fields
    in ``changes`` replaced by their bytes. Every changed field must be one the base has."""
    head, fields = split_layered_form(base_full)
    absent = [name for name in changes if name not in fields]
    if absent:
        raise ValueError(f"the base form has no {absent[0]} field")
    return head + b"".join(changes.get(name, value) for name, value in fields.items())


def variant_bytes(full: bytes, base_index: int, base_full: bytes) -> bytes | None:
    """``full`` (a form written in full) as the variant of form ``base_index``, whose bytes in full are
    ``base_full``; None where it cannot be one (another kind or layout: other ``mu``, ``sigma`` or layers) or
    equals the base."""
    if not full or full[0] != LAYERED_KIND or not base_full or base_full[0] != LAYERED_KIND:
        return None
    head, fields = split_layered_form(full)
    base_head, base_fields = split_layered_form(base_full)
    if head != base_head:
        return None
    changed = [i for i, name in enumerate(VARIANT_FIELDS) if name in fields and fields[name] != base_fields[name]]
    if not changed:
        return None
    index = bytearray()
    value = base_index
    while True:
        index.append((value & 0x7F) | (0x80 if value >> 7 else 0))
        value >>= 7
        if not value:
            break
    return (bytes([VARIANT_KIND]) + bytes(index) + bytes([sum(1 << i for i in changed)])
            + b"".join(fields[VARIANT_FIELDS[i]] for i in changed))


def best_variant(full: bytes, earlier: Sequence[bytes]) -> bytes:
    """How a writer writes a form (§3.2, informative): as the variant of the earlier form (given written in full)
    that takes the fewest bytes, the first on a tie, where that is shorter than ``full``; else ``full``."""
    best = full
    for index, base in enumerate(earlier):
        candidate = variant_bytes(full, index, base)
        if candidate is not None and len(candidate) < len(best):
            best = candidate
    return best

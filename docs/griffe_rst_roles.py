"""Griffe extension of the documentation site: Sphinx roles in docstrings shown as code.

The library's numpydoc docstrings name other objects with Sphinx roles
(``:func:`~brdfcodec.codec.encode```), which Markdown would print literally.
This turns each into inline code of the name (the last component for ``~``)
before mkdocstrings renders the docstring. Loaded by ``mkdocs.yml``
(``extensions``); it changes nothing but the rendered text.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|exc|obj|const|term|ref):`(~?)([^`<]*?)(?:\s*<([^`>]*)>)?`")


def _code(match: re.Match[str]) -> str:
    short, text, target = match.group(1), match.group(2).strip(), match.group(3)
    name = text if text and not target else (text or target or "")
    if short:
        name = name.rsplit(".", 1)[-1]
    return f"`{name}`"


def without_roles(text: str) -> str:
    """``text`` with every Sphinx role replaced by inline code."""
    return _ROLE.sub(_code, text)


class RstRoles(griffe.Extension):
    """Replace Sphinx roles in every docstring by inline code."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:  # noqa: ARG002
        if obj.docstring is not None:
            obj.docstring.value = without_roles(obj.docstring.value)

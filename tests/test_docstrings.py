"""The examples in the public docstrings run and print what they say (doctest)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import numpy as np
import pytest

import brdfcodec

_OPTIONAL = {"brdfcodec.render.mitsuba_bsdf": "mitsuba"}


def _module_names() -> list[str]:
    return sorted(info.name for info in pkgutil.walk_packages(brdfcodec.__path__, "brdfcodec.")
                  if not info.name.endswith("__main__"))


@pytest.mark.parametrize("name", _module_names())
@pytest.mark.slow
def test_docstring_examples(name: str) -> None:
    if name in _OPTIONAL:
        pytest.importorskip(_OPTIONAL[name])
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    # NumPy's default printing, whatever an earlier test or library (legacy="1.13") left behind.
    with np.printoptions(legacy=False, sign="-", floatmode="maxprec", precision=8, suppress=False, linewidth=75):
        for test in finder.find(module, name):  # each example sees its module's names
            runner.run(test)
    failed, attempted = runner.summarize(verbose=False)
    assert failed == 0, f"{failed} of {attempted} docstring examples of {name} failed (see the output above)"


def test_the_public_api_has_examples() -> None:
    """The entry points a newcomer reads first show how they are called."""
    from brdfcodec import codec, representation
    from brdfcodec.representation import metrics

    for obj in (codec.encode, codec.BrdfDecoder, codec.MaterialLibrary, metrics.relae_between_mapped,
                representation.mapping, representation.units, representation.network_io):
        assert ">>>" in (obj.__doc__ or ""), obj

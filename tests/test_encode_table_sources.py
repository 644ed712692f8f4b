"""Tables as :func:`brdfcodec.encode` sources: a NumPy array of one material (or a stack of them) encodes as its
:class:`~brdfcodec.io.merl.MerlBRDF` does, and a source of another kind, shape or with values that are not finite is
refused with an error naming the source, before any file is written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from brdfcodec.codec.oneshot import compress, encode
from brdfcodec.io.merl import MerlBRDF


def test_a_table_encodes_as_its_merl_brdf(tiny_model_folder: Path, analytic_tables: dict[str, MerlBRDF]) -> None:
    gold, chrome = analytic_tables["gold"], analytic_tables["chrome"]
    expected = encode([gold, chrome], names=["gold", "chrome"], model=tiny_model_folder, measure_error=False)
    as_list = encode([gold.values, chrome.values], names=["gold", "chrome"],
                     model=tiny_model_folder, measure_error=False)
    stacked = encode(np.stack([gold.values, chrome.values]), names=["gold", "chrome"], model=tiny_model_folder,
                     measure_error=False)
    assert as_list == expected and stacked == expected
    # one table alone is one material (not its three channels), named as any unnamed source is
    alone = encode(gold.values, model=tiny_model_folder, measure_error=False)
    assert alone == encode([gold.values], names=["material-0"], model=tiny_model_folder, measure_error=False)


@pytest.mark.parametrize(("source", "error", "message"), [
    (np.zeros((3, 90, 90, 90)), ValueError, r"source 1: a table must be real numbers of shape \(3, 90, 90, 180\)"),
    (np.zeros((3, 90, 90, 180), dtype=np.complex128), ValueError, r"source 1: a table must be real numbers"),
    (np.full((3, 90, 90, 180), np.nan), ValueError, r"source 1: the table holds 4374000 entries that are not finite"),
    ([[1.0, 2.0]], TypeError, r"source 1: expected a MERL \.binary or RGL \.bsdf path, .* got list"),
    (42, TypeError, r"source 1: .* got int"),
])
def test_a_source_of_another_kind_is_refused_before_a_file_is_written(
    tiny_model_folder: Path, analytic_tables: dict[str, MerlBRDF], tmp_path: Path, source: object,
    error: type[Exception], message: str,
) -> None:
    output = tmp_path / "out.bvae"
    with pytest.raises(error, match=message):
        compress([analytic_tables["gold"].values, source], output, model=tiny_model_folder, measure_error=False)
    assert not output.exists()

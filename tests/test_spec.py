"""The normative spec and the code agree on every constant the spec states."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from brdfcodec import conventions
from brdfcodec.datasets.hdf5 import DATASET_FORMAT, DATASET_FORMAT_VERSION
from brdfcodec.io.merl import MERL_FILE_SIZE
from brdfcodec.representation.mask import horizon_mask

SPEC = Path(__file__).resolve().parents[1] / "spec"


def conventions_text() -> str:
    return (SPEC / "conventions.md").read_text(encoding="utf-8")


def test_version_matches() -> None:
    assert re.search(rf"^Version {re.escape(conventions.CONVENTIONS_VERSION)} ", conventions_text(), re.M)
    dataset_spec = (SPEC / "dataset-format.md").read_text(encoding="utf-8")
    assert f"Format version {DATASET_FORMAT_VERSION} " in dataset_spec
    assert f'`"{DATASET_FORMAT}"`' in dataset_spec


@pytest.mark.parametrize("name", ["conventions.md", "model.md", "dataset-format.md"])
def test_version_line_is_the_latest_change_log_entry(name: str) -> None:
    """The version at the top of a spec is the newest one in its change log."""
    text = (SPEC / name).read_text(encoding="utf-8")
    top = re.search(r"^(?:Version|Format version) ([0-9.]+)(?: \(document revision ([0-9.]+)\))?", text, re.M)
    log = re.findall(r"^- ([0-9.]+) \(", text.split("## Change log", 1)[-1], re.M)
    assert top is not None and log, f"{name}: no version line or no change log"
    latest = top.group(2) or top.group(1)  # a file format version may stay while its document is revised
    assert latest == max(log, key=lambda v: tuple(int(p) for p in v.split("."))), name


@pytest.mark.parametrize("name", ["conventions.md", "model.md", "dataset-format.md", "bvae-format.md"])
def test_the_spec_index_lists_each_document_at_its_version(name: str) -> None:
    """``spec/README.md``'s table names the version each document's first lines state."""
    text = (SPEC / name).read_text(encoding="utf-8")
    top = re.search(r"^(?:Version|Format version) ([0-9.]+)(?: \(document revision ([0-9.]+)\))?", text, re.M)
    assert top is not None, name
    row = re.search(rf"^\| \[{re.escape(name)}\]\({re.escape(name)}\) \| ([^|]+) \|",
                    (SPEC / "README.md").read_text(encoding="utf-8"), re.M)
    assert row is not None, f"spec/README.md does not list {name}"
    listed = row.group(1).strip()
    wanted = top.group(1) if top.group(2) is None else f"{top.group(1)} (revision {top.group(2)})"
    assert listed == wanted, f"spec/README.md lists {name} at {listed!r}, the document says {wanted!r}"


def test_kept_slices_match() -> None:
    match = re.search(r"KEPT_PHI_D_SLICES = ([0-9, ]+)", conventions_text())
    assert match is not None
    assert tuple(int(v) for v in match.group(1).split(",")) == conventions.KEPT_PHI_D_SLICES


def test_numbers_stated_in_the_spec_match() -> None:
    text = conventions_text()
    assert f"**{MERL_FILE_SIZE:,} bytes**" in text
    assert "S = (1.0, 1.15, 1.66) / 1500" in text
    np.testing.assert_allclose(conventions.MERL_COLOR_SCALE, np.array([1.0, 1.15, 1.66]) / 1500)
    assert f"[0, `MAPPED_MAX`] = [0, {conventions.MAPPED_MAX:g}]" in text
    assert conventions.HORIZON_COS_MIN == 1e-9 and "cos θ > 1e-9 (`HORIZON_COS_MIN`)" in text
    assert conventions.BIN_TOLERANCE == 1e-9 and "τ = 1e-9 (`BIN_TOLERANCE`)" in text
    assert f"ε = {conventions.EPSILON:g}" in text
    assert f"{100 * horizon_mask().mean():.2f} % of the 90×90×180 grid" in text


def test_model_spec_counts_match() -> None:
    from brdfcodec.models.network import valid_input_index

    text = (SPEC / "model.md").read_text(encoding="utf-8")
    assert f"{valid_input_index().numel():,} of" in text
    assert "β = 12" in text

"""Lean files (issue 40): what ``bvae compress --bytes N`` writes is the payloads, the names and little else.

``--bytes N`` caps what each material adds to the file beyond its name (its payload and its descriptor in the
index, ``spec/bvae-format.md`` §3.3); the file adds one fixed header (decoder and basis hashes, the form table,
two CRC-32s). Provenance is opt-in (``--provenance``).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from brdfcodec.cli import main
from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.format.bvae import PROVENANCE_KEYS, read_bvae
from brdfcodec.io.merl import write_merl

#: What a file may add beyond its materials' budgets and names: its fixed header (about 100 B) and a form table.
FILE_OVERHEAD = 1024


def _compress(capsys: pytest.CaptureFixture[str], *argv: str) -> None:
    assert main(["compress", *argv]) == 0
    capsys.readouterr()


def _assert_lean(path: Path, budget: int) -> None:
    """Each material adds at most ``budget`` bytes beyond its name; the file at most the fixed overhead more."""
    parsed = read_bvae(path)
    entries = parsed.header.entries
    names = sum(len(e.name.encode("utf-8")) for e in entries)
    for entry in entries:
        assert entry.length + entry.descriptor_bytes <= budget, entry
    assert path.stat().st_size <= len(entries) * budget + names + FILE_OVERHEAD
    assert all(not r.meta for r in parsed.records) and b"created_by" not in path.read_bytes()


@pytest.mark.slow
def test_one_material_at_64_bytes_is_at_most_200_bytes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "gold-metallic-paint.binary"  # a 19-byte name, as MERL's are
    write_merl(source, ANALYTIC_PRESETS["gold"].to_merl())
    out = tmp_path / "gold.bvae"
    _compress(capsys, str(source), "-o", str(out), "--bytes", "64", "--no-measure", "--effort", "0")
    assert out.stat().st_size <= 200
    _assert_lean(out, 64)
    # --provenance keeps what the default leaves out, and info shows it per record.
    kept = tmp_path / "kept.bvae"
    _compress(capsys, str(source), "-o", str(kept), "--bytes", "64", "--effort", "0", "--provenance")
    (record,) = read_bvae(kept).records
    assert {"source_sha256", "relae", "rate", "effort", "encoder_sha256"} <= set(record.meta) <= set(PROVENANCE_KEYS)
    assert record.meta["rate"]["record_bytes"] <= 64
    assert kept.stat().st_size > out.stat().st_size + 100


@pytest.mark.slow
def test_every_material_of_a_library_keeps_within_its_budget(
    analytic_training_set: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The fast variant of the 100-material acceptance: 12 materials, each within 64 B beyond its name."""
    out = tmp_path / "lib.bvae"
    _compress(capsys, str(analytic_training_set), "-o", str(out), "--bytes", "64", "--no-measure", "--effort", "0")
    _assert_lean(out, 64)
    assert read_bvae(out).header.basis_sha256 is not None  # stated once, in the header
    assert main(["info", "--json", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    # 2.3: packed basis layers; 2.4 when rate control (--basis-coding auto) entropy-codes one (§4.8)
    # 2.6: short references (spec §3.1); 2.7 where the materials' forms differ in a prior, a grid or a first vector,
    # written as variants of the first (§3.2)
    assert summary["format_version"] == "2.7" and summary["metadata"] is False
    assert read_bvae(out).header.form_count > 1
    for item in summary["materials"]:
        # a compact base without σ (format 2.2), μ coded in the layer's stream (2.5), or (format 2.1) no latent at
        # all where that was better
        assert (item["mu"], item["sigma"]) in {("int8-fixed", "none"), ("int8", "none"), ("coded", "none"),
                                               ("none", "none")}
        assert item["basis"]["count"] >= 45 and item["record_bytes"] <= 64 and "source_kind" not in item


@pytest.mark.slow  # minutes on 2 cores: 100 materials encoded at four budgets
@pytest.mark.parametrize("budget", [16, 32, 64, 128])
def test_a_hundred_materials_cost_their_budgets_and_names(
    hundred_materials: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], budget: int
) -> None:
    out = tmp_path / "lib.bvae"
    _compress(capsys, str(hundred_materials), "-o", str(out), "--bytes", str(budget), "--no-measure",
              "--effort", "0")
    assert len(read_bvae(out).records) == 100
    _assert_lean(out, budget)


@pytest.fixture(scope="module")
def hundred_materials(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dataset (inputs only) of the 7 analytic presets and 93 random analytic materials."""
    from brdfcodec.datasets.hdf5 import build_dataset
    from brdfcodec.datasets.sources import analytic_sources

    path = tmp_path_factory.mktemp("hundred") / "hundred.h5"
    build_dataset(path, analytic_sources(random_count=93), source_kind="analytic", description="100 analytic",
                  include_tables=False, progress=False)
    return path

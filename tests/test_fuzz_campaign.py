"""The fuzz campaign of ``bvae bench fuzz`` (issue 49): a short seeded run finds no bug, and the harness itself
finds what it is meant to find.

The long campaign (≥ 100,000 inputs) is ``bvae bench fuzz -o reports/fuzz/campaign --workers 2``; its summary
is ``reports/fuzz/campaign/summary.json``.
"""

from __future__ import annotations

import json
import random
import struct
import zlib
from pathlib import Path

import pytest

from brdfcodec.cli.fuzz_campaign import (
    BUG_CLASSES,
    Seeds,
    _Checker,
    make_input,
    make_seeds,
    run_campaign,
    write_input,
)
from brdfcodec.report.fuzz_bvae import bvae_fields, fix_bvae, mutate_bvae

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="module")
def seed_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("fuzz-seeds")
    make_seeds(folder, cli=False)
    return folder


def test_fields_cover_a_layered_file_and_crcs_are_recomputed(seed_folder: Path) -> None:
    from brdfcodec.format.bvae import parse_bvae

    data = (seed_folder / "w-basis-detail.bvae").read_bytes()
    names = [field.name for field in bvae_fields(data)]
    for name in ("latent_dim", "basis", "form0.layers", "form0.first", "form0.detail_form", "record0.count",
                 "record0.step", "record0.detail_length", "payload_crc32", "metadata", "payload"):
        assert name in names
    changed = bytearray(data)
    changed[-1] ^= 0x01  # a payload byte: both CRCs break; fix_bvae mends them and the file reaches its values
    assert zlib.crc32(bytes(changed)) != zlib.crc32(data)
    mended = fix_bvae(bytes(changed))
    assert mended[-1] == changed[-1]
    try:
        parse_bvae(mended)
    except Exception as error:  # noqa: BLE001 - whatever refuses it, it is not a checksum
        assert "CRC" not in str(error)


def test_fields_of_a_file_with_short_references_and_a_coded_mu() -> None:
    """bvae compress writes short references (format 2.6), coded-μ forms (2.5) and form variants (2.7): the fields
    the mutators aim at are where the reader reads them, up to the payload CRC-32 that fix_bvae mends."""
    from brdfcodec.errors import BvaeChecksumError
    from brdfcodec.format.bvae import parse_bvae

    vectors = Path(__file__).resolve().parents[1] / "spec" / "vectors" / "valid"
    for name, wanted in (("reference-decode-short", "basis"), ("coded-mu", "form0.mu_step"),
                         ("form-variants", "form3.changes")):
        data = (vectors / f"{name}.bvae").read_bytes()
        fields = {field.name: field for field in bvae_fields(data)}
        assert {wanted, "payload_crc32", "payload"} <= set(fields), name
        assert fields["latent_dim"].start == 24 + (8 if name.endswith(("short", "variants")) else 32)
        assert data[fields["payload_crc32"].start : fields["payload_crc32"].end] == struct.pack(
            "<I", zlib.crc32(data[fields["payload"].start :]))
        changed = bytearray(data)
        changed[-1] ^= 0x01
        try:
            parse_bvae(fix_bvae(bytes(changed)))
        except Exception as error:  # noqa: BLE001 - a payload byte flipped may be refused, but not by a CRC-32
            assert not isinstance(error, BvaeChecksumError), (name, error)


def test_mutants_are_deterministic(seed_folder: Path) -> None:
    seed = (seed_folder / "w-graft-latent.bvae").read_bytes()
    first = [mutate_bvae(seed, random.Random(f"s{i}"), seed) for i in range(50)]
    assert first == [mutate_bvae(seed, random.Random(f"s{i}"), seed) for i in range(50)]
    assert len({data for data, _ in first}) > 40


def test_the_checker_reports_an_untyped_error_and_info_accepting_what_decode_refuses(
        seed_folder: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The oracle can fail: a reader that raises KeyError, a decoder that refuses, a decode of NaN."""
    import numpy as np

    from brdfcodec.cli import info_command
    from brdfcodec.codec import library
    from brdfcodec.errors import BvaeFormatError

    checker = _Checker()
    path = tmp_path / "a.bvae"
    path.write_bytes((seed_folder / "w-projected.bvae").read_bytes())
    item = {"surface": "bvae"}
    assert checker.run(item, path, full=False) == ("accepted", "")
    with monkeypatch.context() as patch:
        patch.setattr(library.DecodedMaterial, "table", lambda self, **kw: np.full((3, 90, 90, 1), np.nan))
        assert checker.run(item, path, full=False)[0] == "non-finite decode"
    with monkeypatch.context() as patch:
        def refuse(self, header, where=""):  # noqa: ANN001, ANN202
            raise BvaeFormatError(where, "refused at decode")
        patch.setattr(type(checker.decoder), "check", refuse)
        outcome, error = checker.run(item, path, full=False)
        assert outcome == "info accepts, decode refuses" and "refused at decode" in error
    with monkeypatch.context() as patch:
        patch.setattr(info_command, "describe_file", lambda p: {}["missing"])
        assert checker.run(item, path, full=False)[0] == "untyped"
    path.write_bytes(b"\x89BVAE\r\n\x1a" + struct.pack("<HHIII", 2, 1, 0, 3, 0) + b"abc")
    assert checker.run(item, path, full=False) == ("refused", "BvaeChecksumError")


@pytest.mark.slow
def test_seeded_mutants_in_process_find_no_bug(seed_folder: Path, tmp_path: Path) -> None:
    """200 seeded inputs checked in this process (the campaign's inputs and oracles, without its worker pool)."""
    import shutil

    from brdfcodec.models.registry import default_model_folder

    run = tmp_path / "run"
    shutil.copytree(seed_folder, run / "seeds")
    bsdf = SHARED / "data/rgl/paper_white_rgb.bsdf"
    plan = {"seed": 11, "batch_size": 200, "bvae_seeds": {p.stem: p.name for p in seed_folder.iterdir()},
            "bsdf_seed": str(bsdf) if bsdf.is_file() else None, "model_seed": str(tmp_path / "model")}
    shutil.copytree(default_model_folder(), tmp_path / "model")  # hard links need one file system
    (run / "plan.json").write_text(json.dumps(plan))
    seeds, checker = Seeds(run, plan), _Checker()
    outcomes: dict[str, list[str]] = {}
    for index in range(200):
        item = make_input(seeds, 11, f"0-{index}")
        outcome, error = checker.run(item, write_input(item, tmp_path / "input", seeds), full=index % 50 == 0)
        outcomes.setdefault(outcome, []).append(f"0-{index} {item['surface']} {item['seed']} {item['how']}: {error}")
    assert not {name: outcomes[name] for name in BUG_CLASSES if name in outcomes}
    assert len(outcomes.get("refused", ())) > 50 and len(outcomes.get("accepted", ())) > 10


@pytest.mark.slow
def test_a_short_campaign_finds_no_bug(seed_folder: Path, tmp_path: Path) -> None:
    """300 seeded inputs (every writer seed, the RGL file when ../shared is there, the model folder): 0 bugs."""
    run = tmp_path / "run"
    (run / "seeds").mkdir(parents=True)
    for seed in seed_folder.iterdir():
        (run / "seeds" / seed.name).write_bytes(seed.read_bytes())
    summary = run_campaign(run, inputs=300, batch_size=150, workers=1, seed=7, cli_seeds=False,
                           shared=SHARED if SHARED.is_dir() else None, timeout=120.0)
    assert summary["inputs"] == 300
    assert summary["bug_counts"] == dict.fromkeys(BUG_CLASSES, 0), json.dumps(summary["bugs"], indent=1)
    assert summary["outcomes"]["refused"] and summary["outcomes"]["accepted"]
    assert summary["per_surface"]["model"]  # model folders are fuzzed too
    assert summary["schema"] == "brdfcodec.rows/1" and summary["study"] == "fuzz"
    assert json.loads((run / "summary.json").read_text())["inputs"] == 300
    again = run_campaign(run, inputs=300, workers=1)  # resumed: nothing left to run
    assert again["inputs"] == 300 and again["outcomes"] == summary["outcomes"]
    seeds = Seeds(run, json.loads((run / "plan.json").read_text()))
    assert make_input(seeds, 7, "1-3")["data"] == make_input(seeds, 7, "1-3")["data"]

"""A model's basis grown in place (``bvae model fit-basis --extend``, ``spec/model.md`` §5 ``basis_prefixes``).

The extended basis keeps the old vectors bit for bit and adds the fit's later ones, orthonormal to them; files
whose basis layers name the old basis keep decoding, to the same bits, within the old basis' vectors only.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from brdfcodec.errors import BasisError
from brdfcodec.layers.basis import extend_factorised_basis, fit_factorised_basis


def _materials(n: int = 7, width: int = 40, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n random materials over 3 colours × ``width`` entries, the first entry invalid in one material."""
    rng = np.random.default_rng(seed)
    values = rng.normal(size=(n, 3 * width)) @ np.diag(np.linspace(3.0, 0.1, 3 * width))
    masks = np.ones_like(values, dtype=bool)
    masks[2, 0] = False
    return values, masks


@pytest.mark.parametrize("storage", ["int8", "float16"])
@pytest.mark.parametrize("size", range(1, 12))
def test_an_extended_basis_keeps_the_old_vectors_bit_for_bit_and_stays_orthonormal(size: int, storage: str) -> None:
    values, masks = _materials()
    old = fit_factorised_basis(values, masks, size)
    fitted = fit_factorised_basis(values, masks, 30)
    grown = extend_factorised_basis(old, fitted, storage=storage)  # type: ignore[arg-type]
    assert len(grown.colours) == 30 and np.array_equal(grown.colour_entries, old.colour_entries)
    assert np.array_equal(grown.products(0, size), old.products(0, size))  # the old vectors, unchanged
    assert np.array_equal(grown.factors[: len(old.factors)], old.factors)
    assert (grown.factors_int8 is not None) == (storage == "int8" and grown.factor_count > len(old.factors))
    vectors = grown.products(0, 30).astype(np.float64)
    # orthonormal up to the rounding of the stored factors: binary16, or 8 bits per slice scale
    tolerance = 5e-3 if storage == "float16" else 4e-2
    assert np.abs(vectors @ vectors.T - np.eye(30)).max() < tolerance
    # It spans what the larger fit spans: every fitted vector lies in it (up to that rounding).
    target = fitted.products(0, 30).astype(np.float64)
    assert np.linalg.norm(target - (target @ vectors.T) @ vectors, axis=1).max() < 2e-2 + tolerance
    assert set(grown.factor_of.tolist()) == set(range(grown.factor_count))  # every factor is used


def test_extending_refuses_a_fit_of_other_entries_or_no_more_vectors() -> None:
    values, masks = _materials()
    old = fit_factorised_basis(values, masks, 6)
    with pytest.raises(BasisError, match="holds 6 vectors"):
        extend_factorised_basis(old, fit_factorised_basis(values, masks, 6))
    other_masks = masks.copy()
    other_masks[0, 5] = False
    with pytest.raises(BasisError, match="other entries"):
        extend_factorised_basis(old, fit_factorised_basis(values, other_masks, 20))


def test_a_leading_part_is_the_same_vectors_under_the_old_name() -> None:
    from brdfcodec.layers.shared_basis import SharedBasis

    values, masks = _materials()
    grown = fit_factorised_basis(values, masks, 20)
    basis = SharedBasis(None, np.arange(3 * len(grown.colour_entries)), "ab" * 32, grown)
    part = basis.leading(7, "cd" * 32)
    assert part.sha256 == "cd" * 32 and part.count == 7
    assert basis.leading(7, "cd" * 32) is part  # made once: decoders ask for it per record
    assert np.array_equal(part.vectors(0, 7), basis.vectors(0, 7))
    weights = np.linspace(-1, 1, 7)
    assert np.array_equal(part.weighted_sum(weights), basis.weighted_sum(weights))
    with pytest.raises(BasisError, match="holds 7"):
        part.vectors(0, 8)
    with pytest.raises(BasisError):
        basis.leading(21, "cd" * 32)


def _manifest_bytes(**changes: object) -> bytes:
    from brdfcodec.models.registry import default_model_folder

    stored = json.loads((default_model_folder() / "model.json").read_text())
    stored.update(changes)
    return json.dumps(stored).encode()


@pytest.mark.parametrize(("prefixes", "message"), [
    ([], "object"),
    ({"AB" * 32: 75}, "hex SHA-256"),
    ({"ab" * 31: 75}, "hex SHA-256"),
    ({"ab" * 32: 0}, "1 … 4095"),
    ({"ab" * 32: True}, "1 … 4095"),
    ({"ab" * 32: 75.0}, "1 … 4095"),
    ({"ab" * 32: 4096}, "1 … 4095"),
    ({f"{i:064x}": 1 for i in range(17)}, "at most 16"),
])
def test_a_manifest_with_malformed_basis_prefixes_is_refused(prefixes: object, message: str, tmp_path) -> None:
    from brdfcodec.models.manifest import parse_manifest

    with pytest.raises(ValueError, match=message):
        parse_manifest(_manifest_bytes(basis_prefixes=prefixes), tmp_path)


def test_basis_prefixes_need_a_basis_and_are_not_the_basis_itself(tmp_path) -> None:
    from brdfcodec.models.manifest import parse_manifest

    own = json.loads(_manifest_bytes())["basis_sha256"]
    with pytest.raises(ValueError, match="not a prefix of itself"):
        parse_manifest(_manifest_bytes(basis_prefixes={own: 10}), tmp_path)
    with pytest.raises(ValueError, match="needs a basis_sha256"):
        parse_manifest(_manifest_bytes(basis_prefixes={"ab" * 32: 10}, basis_sha256=None), tmp_path)
    read = parse_manifest(_manifest_bytes(basis_prefixes={"ab" * 32: 10}), tmp_path)
    assert read.basis_prefixes == {"ab" * 32: 10}


@pytest.mark.slow
def test_fit_basis_extend_keeps_every_old_file_decoding_to_the_same_bits(
    tiny_model_folder, analytic_training_set, tmp_path, monkeypatch, capsys
) -> None:
    import shutil

    from brdfcodec.cli.main import main
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import DecoderReference
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.format.writer import encode_bvae
    from brdfcodec.layers.basis import quantise_coefficients
    from brdfcodec.models.store import load_manifest

    folder = tmp_path / "model"
    shutil.copytree(tiny_model_folder, folder)
    dataset = str(analytic_training_set)
    assert main(["model", "fit-basis", str(folder), "--dataset", dataset, "--count", "12"]) == 0
    old = load_manifest(folder)
    assert old.basis_sha256 is not None and old.basis_prefixes == {}
    rng = np.random.default_rng(0)
    latent = old.config.latent_dim
    record = LayeredRecord("old", rng.normal(size=latent), np.ones(latent), basis=quantise_coefficients(
        old.basis_sha256, rng.normal(0, 3, size=10), 2, 6), compact_sigma=True)
    before = BrdfDecoder(folder).decode(record, masked="zero")
    capsys.readouterr()

    # A count not above the basis' size, or --extend with --replace: refused, nothing written.
    kept = ((folder / "basis.safetensors").read_bytes(), (folder / "model.json").read_bytes())
    assert main(["model", "fit-basis", str(folder), "--dataset", dataset, "--count", "12", "--extend"]) == 1
    assert "extending it needs a count above that" in capsys.readouterr().err
    assert main(["model", "fit-basis", str(folder), "--dataset", dataset, "--count", "30", "--extend",
                 "--replace"]) == 2
    assert "not allowed with argument --extend" in capsys.readouterr().err
    assert ((folder / "basis.safetensors").read_bytes(), (folder / "model.json").read_bytes()) == kept

    assert main(["model", "fit-basis", str(folder), "--dataset", dataset, "--count", "30", "--extend"]) == 0
    assert f"its first 12 are basis {old.basis_sha256}" in capsys.readouterr().out
    grown = load_manifest(folder)
    assert grown.basis_sha256 != old.basis_sha256 and grown.basis_prefixes == {old.basis_sha256: 12}
    decoder = BrdfDecoder(folder)
    assert decoder.shared_basis is not None and decoder.shared_basis.count == 30
    assert np.array_equal(decoder.decode(record, masked="zero"), before)  # the old file's record: the same bits

    # The old basis is the first 12 vectors only: a record naming it past them is refused, as before.
    past = LayeredRecord("past", record.mu, record.sigma, basis=quantise_coefficients(
        old.basis_sha256, np.ones(8), 6, 0), compact_sigma=True)
    with pytest.raises(BasisError, match="holds 12"):
        decoder.decode(past)

    # bvae info finds the old basis through the prefix, and refuses the record past it.
    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(folder))
    reference = DecoderReference(grown.decoder_sha256, grown.name)
    for name, records, code in (("old.bvae", [record], 0), ("past.bvae", [past], 1)):
        (tmp_path / name).write_bytes(encode_bvae(records, reference))
        assert main(["info", str(tmp_path / name)]) == code
    err = capsys.readouterr().err
    assert "holds 12" in err and "Traceback" not in err
    # Extending again keeps both earlier bases decodable.
    assert main(["model", "fit-basis", str(folder), "--dataset", dataset, "--count", "40", "--extend"]) == 0
    again = load_manifest(folder)
    assert again.basis_prefixes == {old.basis_sha256: 12, grown.basis_sha256: 30}
    assert np.array_equal(BrdfDecoder(folder).decode(record, masked="zero"), before)


def test_new_vectors_are_made_orthogonal_to_a_current_basis_that_the_fit_does_not_repeat() -> None:
    # The current basis from other values over the same entries: the fit's later vectors are not orthogonal to it
    # as they come, so the extension must make them so.
    values, masks = _materials()
    other = values + np.random.default_rng(1).normal(0, 1.0, size=values.shape)
    old = fit_factorised_basis(other, masks, 6)
    grown = extend_factorised_basis(old, fit_factorised_basis(values, masks, 20))
    vectors = grown.products(0, 20).astype(np.float64)
    assert np.abs(vectors @ vectors.T - np.eye(20)).max() < 5e-3


@functools.cache
def _grown_in_8_bits(width: int = 8200) -> tuple:
    """A basis of 6 binary16 vectors extended to 20 in 8 bits, over entries spanning two kept slices (made once:
    callers do not change it)."""
    values, masks = _materials(n=9, width=width)
    old = fit_factorised_basis(values, masks, 6)
    return old, extend_factorised_basis(old, fit_factorised_basis(values, masks, 20))


def test_eight_bit_factors_are_within_half_a_step_of_the_values_they_store() -> None:
    from brdfcodec.layers.basis import quantise_factors

    rng = np.random.default_rng(3)
    entries = np.arange(0, 3 * 8100, 3)  # three kept slices
    rows = rng.standard_t(3, size=(4, len(entries)))
    rows[1, entries < 8100] = 0.0  # a slice of zeros: scale 1, values 0
    coarse, scales = quantise_factors(rows, entries)
    assert coarse.dtype == np.int8 and scales.dtype == np.float32 and scales.shape == (4, 21)
    assert scales[1, 0] == 1 and not coarse[1, entries < 8100].any() and (scales[:, 3:] == 1).all()
    step = scales[:, entries // 8100].astype(np.float64)
    assert np.all(np.abs(coarse * step - rows) <= step / 2 * (1 + 1e-6))
    assert np.abs(coarse).max() == 127  # the largest value of each slice takes the full range


def test_an_eight_bit_basis_file_reads_back_to_the_same_vectors_and_grows_again(tmp_path) -> None:
    from brdfcodec.layers.basis import load_shared_basis, write_factorised_basis

    old, grown = _grown_in_8_bits()
    assert grown.factors_int8 is not None and len(grown.factors) == len(old.factors)
    sha = write_factorised_basis(tmp_path / "basis.safetensors", grown)
    read = load_shared_basis(tmp_path / "basis.safetensors", sha)
    assert read.factorised is not None and read.count == 20
    assert np.array_equal(read.vectors(0, 20), grown.products(0, 20))
    assert np.array_equal(read.vectors(0, 6), old.products(0, 6))  # the binary16 vectors, bit for bit
    # the 8-bit rows as spec/model.md §5 defines them: integer times the scale of the column's kept slice
    fine = len(old.factors)
    slice_of = grown.colour_entries // 8100
    assert len(np.unique(slice_of)) == 2
    spec = np.empty((len(grown.factors_int8), len(slice_of)), dtype=np.float32)
    for kept in np.unique(slice_of):
        columns = slice_of == kept
        spec[:, columns] = grown.factors_int8[:, columns].astype(np.float32) * grown.factor_slice_scales[:, [kept]]
    assert np.array_equal(read.factorised.factors32[fine:], spec)
    # a leading part that reaches into the 8-bit rows is the same vectors, and sums over them the same way
    part = read.leading(15, "cd" * 32)
    assert np.array_equal(part.vectors(0, 15), read.vectors(0, 15))
    weights = np.linspace(-1, 1, 15, dtype=np.float32)
    assert np.array_equal(part.weighted_sum(weights), read.weighted_sum(weights))
    # extended again, the 8-bit rows stay bit for bit; binary16 rows cannot follow them
    values, masks = _materials(n=9, width=8200)
    again = extend_factorised_basis(grown, fit_factorised_basis(values, masks, 30))
    assert np.array_equal(again.factors_int8[: len(grown.factors_int8)], grown.factors_int8)
    assert np.array_equal(again.products(0, 20), grown.products(0, 20))
    with pytest.raises(BasisError, match="8 bits"):
        extend_factorised_basis(grown, fit_factorised_basis(values, masks, 30), storage="float16")


@pytest.mark.parametrize(("change", "message"), [
    ({"factor_slice_scales": None}, "come together"),
    ({"factors_int8": lambda t: t.astype(np.int16)}, "int8"),
    ({"factors_int8": lambda t: t[:, :-1]}, "columns"),
    ({"factor_slice_scales": lambda t: t[:, :20]}, "shape"),
    ({"factor_slice_scales": lambda t: t.astype(np.float64)}, "float32"),
    ({"factor_slice_scales": lambda t: -t}, "positive"),
    ({"factor_slice_scales": lambda t: t * np.inf}, "positive"),
    ({"factor_of": lambda t: t + 1}, "factor rows"),
])
def test_a_malformed_eight_bit_basis_file_is_refused_with_the_problem(change, message, tmp_path) -> None:
    from safetensors.numpy import save_file

    from brdfcodec.io.hashing import sha256_of_file
    from brdfcodec.layers.basis import load_shared_basis

    _, grown = _grown_in_8_bits()
    tensors = {"factors": grown.factors, "colours": grown.colours, "factor_of": grown.factor_of,
               "colour_entries": grown.colour_entries, "factors_int8": grown.factors_int8,
               "factor_slice_scales": grown.factor_slice_scales}
    for name, how in change.items():
        if how is None:
            del tensors[name]
        else:
            tensors[name] = np.ascontiguousarray(how(tensors[name]))
    path = tmp_path / "basis.safetensors"
    save_file(tensors, str(path))
    with pytest.raises(BasisError, match=message) as caught:
        load_shared_basis(path, sha256_of_file(path))
    assert str(path) in str(caught.value)

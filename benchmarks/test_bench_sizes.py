"""File size per material of .bvae files holding 1 and 100 materials (sizes, not times; printed and recorded)."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.format.bvae import DecoderReference, LatentRecord, encode_bvae

DECODER = DecoderReference("e1" * 32, "bvae-nbrdf-proxy-small-v1")


def library(count: int, with_meta: bool) -> list[LatentRecord]:
    rng = np.random.default_rng(0)
    records = []
    for i in range(count):
        meta = {
            "source_sha256": rng.bytes(32).hex(),
            "encoder_sha256": "87" * 32,
            "relae": {"mapped": float(rng.uniform(0.02, 0.1)), "linear": float(rng.uniform(0.1, 0.5))},
        } if with_meta else {}
        records.append(LatentRecord(f"material-{i:03d}", rng.normal(size=8), np.exp(rng.normal(size=8) - 3), meta))
    return records


def size_table() -> list[dict[str, object]]:
    rows = []
    for count in (1, 100):
        for with_meta in (False, True):
            for dtype in ("float32", "float16"):
                # short references, as bvae compress writes them (format 2.6)
                size = len(encode_bvae(library(count, with_meta), DECODER, latent_dtype=dtype,  # type: ignore[arg-type]
                                       short_references=True))
                rows.append({"materials": count, "metadata": with_meta, "latent_dtype": dtype, "bytes": size,
                             "bytes_per_material": size / count})
    return rows


@pytest.mark.parametrize("count", [1, 100])
def test_bvae_size_per_material(benchmark, count: int) -> None:
    benchmark.group = "bvae-size"
    records = library(count, True)
    data = benchmark(encode_bvae, records, DECODER)
    benchmark.extra_info["bytes"] = len(data)
    benchmark.extra_info["bytes_per_material"] = len(data) / count
    for row in size_table():
        benchmark.extra_info[f"{row['materials']}-{'meta' if row['metadata'] else 'bare'}-{row['latent_dtype']}"] = (
            row["bytes_per_material"]
        )


if __name__ == "__main__":
    for row in size_table():
        print(row)

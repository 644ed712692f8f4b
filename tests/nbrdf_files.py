"""Self-made NBRDF fits in the published layout (``NAME.h5`` weights, ``NAME.json`` Keras description, a zip).

The layout is that of ``merl-nbrdf-90.zip`` (``../shared/data/README.md``):
HDF5 datasets ``dense_N/dense_N/kernel:0`` and ``bias:0``, kernels (in, out),
and a Keras ``Sequential`` description of Dense 21 (ReLU), Dense 21 (ReLU),
Dense 3 (linear), then a Lambda layer (``exp(x) − 1``).
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import h5py
import numpy as np

Layers = list[tuple[np.ndarray, np.ndarray]]


def keras_description(activations: tuple[str, str, str] = ("relu", "relu", "linear")) -> str:
    """A Keras model description of the NBRDF network (other activations make another network)."""
    layers = [{"class_name": "Dense", "config": {"name": f"dense_{n}", "units": units, "activation": activation}}
              for n, (units, activation) in enumerate(zip((21, 21, 3), activations, strict=True), start=1)]
    layers.append({"class_name": "Lambda", "config": {"name": "lambda_1", "function_type": "lambda"}})
    return json.dumps({"class_name": "Sequential", "config": {"name": "sequential_1", "layers": layers},
                       "keras_version": "2.2.4", "backend": "tensorflow"})


def write_fit(path_or_buffer: Path | io.BytesIO, layers: Layers) -> None:
    """Write NBRDF weights as Keras stores them."""
    with h5py.File(path_or_buffer, "w") as handle:
        for number, (kernel, bias) in enumerate(layers, start=1):
            group = handle.create_group(f"dense_{number}/dense_{number}")
            group["kernel:0"] = kernel.astype(np.float32)
            group["bias:0"] = bias.astype(np.float32)


def constant_fit(rgb: tuple[float, float, float]) -> Layers:
    """A network whose output is exp(log1p(rgb)) − 1 = rgb (1/sr) everywhere."""
    return [
        (np.zeros((6, 21)), np.zeros(21)),
        (np.zeros((21, 21)), np.zeros(21)),
        (np.zeros((21, 3)), np.log1p(np.asarray(rgb))),
    ]


def lobe_fit(seed: int) -> Layers:
    """A small random network with a lobe that varies over the grid (outputs of order 0.01–1 /sr)."""
    rng = np.random.default_rng(seed)
    return [
        (rng.normal(0, 0.5, (6, 21)), rng.normal(0, 0.1, 21)),
        (rng.normal(0, 0.2, (21, 21)), rng.normal(0, 0.1, 21)),
        (rng.normal(0, 0.2, (21, 3)), np.log1p(rng.uniform(0.02, 0.2, 3))),
    ]


def write_fit_files(folder: Path, name: str, layers: Layers, *, description: str | None = None) -> Path:
    """``folder/NAME.h5`` and ``folder/NAME.json``; returns the ``.h5``."""
    folder.mkdir(parents=True, exist_ok=True)
    write_fit(folder / f"{name}.h5", layers)
    (folder / f"{name}.json").write_text(keras_description() if description is None else description)
    return folder / f"{name}.h5"


def write_fit_archive(path: Path, fits: dict[str, Layers], *, folder: str = "merl-nbrdf") -> Path:
    """A zip laid out as the published archives: ``FOLDER/NAME.h5``, ``FOLDER/NAME.json``, ``FOLDER/LICENSE``."""
    with zipfile.ZipFile(path, "w") as handle:
        for name, layers in fits.items():
            buffer = io.BytesIO()
            write_fit(buffer, layers)
            handle.writestr(f"{folder}/{name}.h5", buffer.getvalue())
            handle.writestr(f"{folder}/{name}.json", keras_description())
        handle.writestr(f"{folder}/LICENSE", "MIT")
    return path

"""``bvae bench fuzz``: a resumable fuzz campaign over ``.bvae`` files, RGL ``.bsdf`` headers and model folders.

Seeds are valid inputs: ``.bvae`` files the command line writes (every record kind: latent, float16, σ, graft,
layered with packed, int8, entropy-coded basis layers and detail layers, basis-only, compact μ, edited records, a
library) and files the library's writer writes (forms the command line picks only for some materials); the RGL
file ``../shared/data/rgl/paper_white_rgb.bsdf`` when it is there; the shipped model folder. Input ``B-I`` (batch
B, item I) is a mutant made by :mod:`brdfcodec.report.fuzz_bvae` or :mod:`brdfcodec.report.fuzz_files` from a
:class:`random.Random` seeded with ``"SEED/B/I"``, so every input can be made again (``--replay``).

Each input runs in a worker process (a pool of ``--workers`` processes, restarted after a crash or a hang) through
what the commands run:

* ``.bvae``: :func:`~brdfcodec.cli.info_command.describe_file` (``bvae info``); when it accepts and the decoder is
  installed, :class:`~brdfcodec.codec.MaterialLibrary` decodes every record (one φd slice; the full table for one
  accepted input in 16), as ``bvae decompress`` does;
* ``.bsdf``: ``describe_file``, which runs every check ``bvae compress`` runs before Mitsuba (Mitsuba is not run);
* model folders: :class:`~brdfcodec.codec.BrdfDecoder` on the folder, its shared basis and
  :func:`~brdfcodec.models.store.load_model` of the encoder, then a decode of one latent code.

Outcomes: ``accepted``, ``accepted, decoder not installed``, ``refused`` (a
:class:`~brdfcodec.errors.BrdfcodecError`), and the bugs: ``untyped`` (any other exception),
``info accepts, decode refuses``, ``non-finite decode``, ``crash`` (the worker died) and ``hang`` (an input ran past
the timeout). Inputs slower than 3 s are listed apart (``slow``). The run folder holds ``plan.json``, the seeds,
``batches.jsonl`` (one line per finished batch: a run resumes after its last), ``progress.log``,
``summary.json`` and ``examples/CLASS/`` (each bug's input and its error).
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import random
import select
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

__all__ = ["BUG_CLASSES", "campaign_summary", "make_input", "make_seeds", "register_fuzz", "replay", "run_campaign",
           "run_fuzz", "write_input"]

BUG_CLASSES = ("untyped", "info accepts, decode refuses", "non-finite decode", "crash", "hang")
SLOW_SECONDS = 3.0
#: The RGL seed, relative to the repository's shared data folder.
RGL_SEED = Path("data/rgl/paper_white_rgb.bsdf")
#: Share of inputs per surface (those without a seed are left out).
SURFACES = {"bvae": 0.87, "bsdf": 0.11, "model": 0.02}
_MODEL_FILES = ("model.json", "decoder.safetensors", "encoder.safetensors", "basis.safetensors")

#: Seeds written by the command line: name → arguments after ``bvae`` ({src}: gold, {src2}: chrome, {dir}: seeds).
CLI_SEEDS: dict[str, list[str]] = {
    "latent": ["compress", "{src}", "-o", "{out}", "--effort", "0"],
    "latent-float16": ["compress", "{src}", "-o", "{out}", "--effort", "0", "--float16"],
    "latent-sigma-provenance": ["compress", "{src}", "-o", "{out}", "--effort", "0", "--sigma", "--provenance"],
    "library": ["compress", "{src}", "{src2}", "-o", "{out}", "--effort", "0", "--provenance"],
    "basis-only-packed": ["compress", "{src}", "-o", "{out}", "--effort", "0", "--bytes", "64", "--latent", "auto"],
    "layered-packed": ["compress", "{src}", "-o", "{out}", "--effort", "0", "--bytes", "64"],
    "layered-int8-sigma": ["compress", "{src}", "-o", "{out}", "--effort", "0", "--bytes", "64", "--basis-coding",
                           "int8", "--sigma"],
    "layered-coded": ["compress", "{src}", "-o", "{out}", "--effort", "0", "--bytes", "96", "--basis-coding",
                      "coded"],
    "layered-detail": ["compress", "{src}", "-o", "{out}", "--effort", "0", "--bytes", "2048"],
    "compact-mu": ["compress", "{src}", "-o", "{out}", "--effort", "0", "--bytes", "20"],
    "layered-float16": ["compress", "{src}", "{src2}", "-o", "{out}", "--effort", "0", "--bytes", "200",
                        "--float16"],
    "graft": ["edit", "graft", "{dir}/latent.bvae", "--values", "0.5,-0.5", "-o", "{out}"],
    "edited-interp": ["edit", "interp", "{dir}/library.bvae", "gold", "chrome", "--t", "0.3", "-o", "{out}"],
    "edited-layered": ["edit", "traverse", "{dir}/layered-detail.bvae", "--dim", "2", "--values", "-1,2", "-o",
                       "{out}"],
}


# --------------------------------------------------------------------------- seeds


def _writer_seeds() -> dict[str, bytes]:
    """Seeds the library's writer makes: forms the command line chooses per material (μ int8 with a step,
    projected bases, a basis with a detail layer), a graft beside a latent record, a library of form variants."""
    import numpy as np

    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import GraftRecord, LatentRecord, encode_bvae
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.detail import encode_detail

    decoder = BrdfDecoder()
    basis_sha = decoder.shared_basis.sha256
    rng = np.random.default_rng(49)
    sigma = np.full(decoder.latent_dim, 0.5)

    def code() -> np.ndarray:
        return rng.normal(0.0, 1.0, decoder.latent_dim)

    def basis(k: int, first: int = 8, project: int = 0) -> BasisLayer:
        return BasisLayer(basis_sha, 0.125, rng.integers(-127, 128, k).astype(np.int8), first, project)

    residual = np.zeros((63, 90, 90))
    residual[:, :10, :10] = rng.normal(0.0, 0.05, (63, 10, 10))
    detail = encode_detail(residual, 0.25)
    records = {
        "w-int8-step-mu": LayeredRecord("a", code(), sigma, basis=basis(10), compact_mu=True, shared_sigma=True),
        "w-projected": LayeredRecord("b", code(), sigma, basis=basis(6, 8, 40), compact_sigma=True),
        "w-basis-detail": LayeredRecord("c", code(), sigma, basis=basis(5, 0), detail=detail, compact_mu=True,
                                        fixed_mu_grid=True, shared_sigma=True),
    }
    seeds = {name: encode_bvae([record], decoder.reference) for name, record in records.items()}
    seeds["w-graft-latent"] = encode_bvae([LatentRecord("p", code(), sigma, {"effort": 1}),
                                           GraftRecord("q", code(), sigma, (1, 4), [0.25, -1.0])], decoder.reference)
    # A library whose forms differ in their first vector and projection: written as variants (format 2.7).
    seeds["w-form-variants"] = encode_bvae(
        [LayeredRecord(name, code(), sigma, basis=basis(6, first, project), compact_sigma=True)
         for name, first, project in (("d", 8, 40), ("e", 0, 40), ("f", 8, 0), ("g", 0, 0))],
        decoder.reference, short_references=True)
    return seeds


def make_seeds(folder: Path, *, cli: bool = True, log: Any = None) -> dict[str, str]:
    """Write the ``.bvae`` seeds into ``folder`` (those already there are kept) and return name → file name.

    ``cli=False`` makes only the writer's seeds (seconds instead of minutes)."""
    folder.mkdir(parents=True, exist_ok=True)
    names: dict[str, str] = {}
    for name, data in _writer_seeds().items():
        (folder / f"{name}.bvae").write_bytes(data)
        names[name] = f"{name}.bvae"
    if not cli:
        return names
    with tempfile.TemporaryDirectory(prefix="bvae-fuzz-src-") as scratch:
        sources = {"src": f"{scratch}/gold.binary", "src2": f"{scratch}/chrome.binary"}
        for name, args in CLI_SEEDS.items():
            out = folder / f"{name}.bvae"
            if not out.exists():
                if not Path(sources["src"]).exists():
                    for preset, path in (("gold", sources["src"]), ("chrome", sources["src2"])):
                        _bvae(["analytic", preset, "-o", path])
                _bvae([a.format(out=out, dir=folder, **sources) for a in args])
                if log:
                    log(f"seed {name}: {out.stat().st_size} bytes")
            names[name] = out.name
    return names


def _bvae(args: list[str]) -> None:
    result = subprocess.run([sys.executable, "-m", "brdfcodec", *args], capture_output=True, text=True)
    if result.returncode:
        raise RuntimeError(f"bvae {' '.join(args)} failed: {result.stderr.strip()}")


# --------------------------------------------------------------------------- inputs


class Seeds:
    """The seeds of a plan, read once: ``.bvae`` bytes by name, the RGL file, the model folder's files."""

    def __init__(self, run: Path, plan: dict[str, Any]) -> None:
        self.bvae = {name: (run / "seeds" / file).read_bytes() for name, file in sorted(plan["bvae_seeds"].items())}
        self.bsdf = Path(plan["bsdf_seed"]).read_bytes() if plan.get("bsdf_seed") else None
        model = plan.get("model_seed")
        if model == "default":  # the shipped model of the checkout that runs the plan
            from brdfcodec.models.registry import default_model_folder

            model = str(default_model_folder())
        self.model_folder = Path(model) if model else None
        self._model_files: dict[str, bytes] | None = None

    def model_files(self) -> dict[str, bytes]:
        if self._model_files is None:
            assert self.model_folder is not None
            self._model_files = {name: (self.model_folder / name).read_bytes() for name in _MODEL_FILES}
        return self._model_files

    def surfaces(self) -> dict[str, float]:
        present = {"bvae": True, "bsdf": self.bsdf is not None, "model": self.model_folder is not None}
        return {surface: share for surface, share in SURFACES.items() if present[surface]}


def make_input(seeds: Seeds, campaign_seed: int, input_id: str) -> dict[str, Any]:
    """The input ``input_id`` (``"B-I"``) of a campaign: ``surface``, ``seed`` (name), ``how`` and ``data``
    (bytes, or for a model folder the files it replaces, name → bytes)."""
    from brdfcodec.report.fuzz_bvae import mutate_bvae
    from brdfcodec.report.fuzz_files import mutate_bsdf, mutate_model_folder

    rng = random.Random(f"{campaign_seed}/{input_id.replace('-', '/')}")
    shares = seeds.surfaces()
    surface = rng.choices(list(shares), weights=list(shares.values()))[0]
    if surface == "bvae":
        name = rng.choice(list(seeds.bvae))
        other = seeds.bvae[rng.choice(list(seeds.bvae))]
        data, how = mutate_bvae(seeds.bvae[name], rng, other)
        if rng.random() < 0.15:  # a second mutation on top of the first
            data2, how2 = mutate_bvae(data, rng, other) if len(data) > 24 else (data, "")
            data, how = data2, f"{how} + {how2}"
        return {"surface": "bvae", "seed": name, "how": how, "data": data}
    if surface == "bsdf":
        assert seeds.bsdf is not None
        data, how = mutate_bsdf(seeds.bsdf, rng)
        return {"surface": "bsdf", "seed": "paper_white_rgb", "how": how, "data": data}
    files, how = mutate_model_folder(seeds.model_files(), rng)
    return {"surface": "model", "seed": "default", "how": how, "data": files}


def write_input(item: dict[str, Any], where: Path, seeds: Seeds) -> Path:
    """Write an input where the checks read it: a ``.bvae`` or ``_rgb.bsdf`` file in ``where``, or a model folder
    ``where/model`` whose files not mutated are hard links to (else copies of) the seed's."""
    where.mkdir(parents=True, exist_ok=True)
    if item["surface"] == "bvae":
        path = where / "fuzz.bvae"
        path.write_bytes(item["data"])
        return path
    if item["surface"] == "bsdf":
        path = where / "fuzz_rgb.bsdf"
        path.write_bytes(item["data"])
        return path
    folder = where / "model"
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir()
    assert seeds.model_folder is not None
    for name in _MODEL_FILES:
        if name in item["data"]:
            (folder / name).write_bytes(item["data"][name])
        else:
            try:
                os.link(seeds.model_folder / name, folder / name)
            except OSError:
                shutil.copyfile(seeds.model_folder / name, folder / name)
    return folder


# --------------------------------------------------------------------------- checks (in a worker)


class _Checker:
    """The oracles, with the shipped decoder loaded once."""

    def __init__(self) -> None:
        from brdfcodec.codec import BrdfDecoder

        self.decoder = BrdfDecoder()

    def run(self, item: dict[str, Any], path: Path, full: bool) -> tuple[str, str]:
        """(outcome, error text) for one written input."""
        from brdfcodec.errors import BrdfcodecError

        stage = "info"
        try:
            if item["surface"] == "model":
                stage = "load"
                return self._model(path), ""
            from brdfcodec.cli.info_command import describe_file

            summary = describe_file(path)
            if item["surface"] == "bsdf":
                return ("accepted" if summary["supported"] else "refused"), ""
            if summary["decoder"]["installed_at"] is None:
                return "accepted, decoder not installed", ""
            stage = "decode"
            return self._decode(path, full), ""
        except BrdfcodecError as error:
            if stage == "decode":
                return "info accepts, decode refuses", f"{type(error).__name__}: {error}"
            return "refused", f"{type(error).__name__}"
        except Exception as error:  # noqa: BLE001 - what the campaign looks for
            text = f"{stage}: {type(error).__name__}: {error}\n{traceback.format_exc(limit=-4)}"
            return ("info accepts, decode refuses" if stage == "decode" else "untyped"), text

    def _decode(self, path: Path, full: bool) -> str:
        import numpy as np

        from brdfcodec.codec import MaterialLibrary

        decoder = self.decoder if self.decoder.reference is not None else None
        with MaterialLibrary(path, decoder=decoder) as library:
            for name in library.names:
                material = library[name]
                table = material.table() if full else material.table(phi_d_bins=[90])
                if not np.isfinite(table).all():
                    return "non-finite decode"
        return "accepted"

    def _model(self, folder: Path) -> str:
        import numpy as np

        from brdfcodec.codec import BrdfDecoder
        from brdfcodec.format.bvae import LatentRecord
        from brdfcodec.models.store import load_model

        decoder = BrdfDecoder(folder)
        decoder.shared_basis  # noqa: B018 - loads and checks the basis file
        load_model(folder, parts=("encoder",))
        record = LatentRecord("m", np.linspace(-1.0, 1.0, decoder.latent_dim), np.ones(decoder.latent_dim))
        table = decoder.decode(record, phi_d_bins=[90])
        if not np.isfinite(table).all():
            return "non-finite decode"
        return "accepted"


def _worker(run: Path) -> int:
    """Run batches named on stdin (``{"batch": B, "start": I}``), one JSON line per input on the protocol pipe."""
    import warnings

    warnings.simplefilter("ignore")
    protocol = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # anything the library prints goes to stderr, not into the protocol
    sys.stdout = sys.stderr
    plan = json.loads((run / "plan.json").read_text())
    seeds = Seeds(run, plan)
    checker = _Checker()
    with tempfile.TemporaryDirectory(prefix="bvae-fuzz-") as scratch:
        if seeds.model_folder is not None:  # a copy on this file system, for hard links
            local = Path(scratch) / "seed-model"
            local.mkdir()
            for name in _MODEL_FILES:
                shutil.copyfile(seeds.model_folder / name, local / name)
            seeds.model_folder = local
        for line in sys.stdin:
            task = json.loads(line)
            for index in range(task["start"], plan["batch_size"]):
                input_id = f"{task['batch']}-{index}"
                protocol.write(json.dumps({"at": input_id}) + "\n")
                item = make_input(seeds, plan["seed"], input_id)
                path = write_input(item, Path(scratch) / "input", seeds)
                full = random.Random(input_id).random() < 1 / 16
                start = time.perf_counter()
                outcome, error = checker.run(item, path, full)
                seconds = time.perf_counter() - start
                protocol.write(json.dumps({"id": input_id, "surface": item["surface"], "seed": item["seed"],
                                           "how": item["how"], "outcome": outcome, "error": error,
                                           "seconds": round(seconds, 3)}) + "\n")
            protocol.write(json.dumps({"done": task["batch"]}) + "\n")
    return 0


# --------------------------------------------------------------------------- the campaign (parent)


class _Pool:
    """One worker process, restarted when it dies or hangs."""

    def __init__(self, run: Path, memory_bytes: int) -> None:
        self.run, self.memory = run, memory_bytes
        self.proc: subprocess.Popen[str] | None = None
        self.pending = b""

    def start(self) -> subprocess.Popen[str]:
        def limits() -> None:
            import resource

            os.nice(10)
            if self.memory:
                resource.setrlimit(resource.RLIMIT_AS, (self.memory, self.memory))

        self.proc = subprocess.Popen(
            [sys.executable, "-m", "brdfcodec.cli.fuzz_campaign", "--worker", str(self.run)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=open(self.run / "worker-stderr.log", "ab"), text=True,
            preexec_fn=limits, env={**os.environ, "BVAE_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"},
        )
        return self.proc

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.proc, self.pending = None, b""

    def _line(self, deadline: float) -> str | None:
        """The worker's next line; None at the deadline, "" when its pipe ends."""
        assert self.proc is not None and self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        while b"\n" not in self.pending:
            ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                return None
            chunk = os.read(fd, 65536)
            if not chunk:
                return ""
            self.pending += chunk
        line, _, self.pending = self.pending.partition(b"\n")
        return line.decode("utf-8")

    def batch(self, batch: int, timeout: float, startup: float) -> list[dict[str, Any]]:
        """Run one batch; returns one row per input (crash and hang rows made here)."""
        rows: list[dict[str, Any]] = []
        start_at, failed_starts, size = 0, 0, _batch_size(self.run)
        while start_at < size:
            proc = self.proc if self.proc is not None and self.proc.poll() is None else self.start()
            assert proc.stdin is not None
            proc.stdin.write(json.dumps({"batch": batch, "start": start_at}) + "\n")
            proc.stdin.flush()
            current, deadline = None, time.monotonic() + timeout + startup
            while True:
                line = self._line(deadline)
                if not line:  # a hang (None: the deadline) or a crash ("": the pipe ended)
                    self.stop()
                    if current is None:  # died between inputs or before the first
                        failed_starts += 1
                        if failed_starts >= 3:
                            raise RuntimeError("a fuzz worker died three times between inputs (see "
                                               f"{self.run / 'worker-stderr.log'})")
                        start_at = int(rows[-1]["id"].split("-")[1]) + 1 if rows else start_at
                        break
                    rows.append({"id": current, "outcome": "hang" if line is None else "crash",
                                 "error": f"no answer within {timeout:.0f} s" if line is None else "the worker died",
                                 "seconds": timeout if line is None else None})
                    start_at = int(current.split("-")[1]) + 1
                    break
                message = json.loads(line)
                if "done" in message:
                    return rows
                if "at" in message:
                    current, deadline = message["at"], time.monotonic() + timeout
                else:
                    rows.append(message)
                    current = None
        return rows


def _batch_size(run: Path) -> int:
    return int(json.loads((run / "plan.json").read_text())["batch_size"])


def run_campaign(run: Path, *, inputs: int, batch_size: int = 500, workers: int = 1, seed: int = 49,
                 cli_seeds: bool = True, shared: Path | None = None, timeout: float = 60.0,
                 memory_bytes: int = 6 << 30, log: Any = None) -> dict[str, Any]:
    """Run (or resume) a campaign of at least ``inputs`` inputs in ``run``; returns and writes the summary.

    Parameters
    ----------
    run : Path
        The run folder; a folder with a ``plan.json`` resumes with that plan (its seed and batch size).
    inputs : int
        Inputs in all, rounded up to whole batches.
    batch_size, workers, seed : int
        Inputs per batch, worker processes, the campaign's random seed.
    cli_seeds : bool
        Also make seeds with the command line (minutes, once per run folder); else the writer's only.
    shared : Path, optional
        The shared data folder holding :data:`RGL_SEED`; no ``.bsdf`` inputs without it.
    timeout : float
        Seconds an input may run (s) before it counts as a hang; the worker is restarted.
    memory_bytes : int
        Address-space limit of each worker (bytes; 0: none).
    """
    say = log or (lambda text: None)
    run.mkdir(parents=True, exist_ok=True)
    plan_path = run / "plan.json"
    if plan_path.exists():
        plan = json.loads(plan_path.read_text())
    else:
        bsdf = (shared / RGL_SEED) if shared is not None and (shared / RGL_SEED).is_file() else None
        plan = {"seed": seed, "batch_size": batch_size,
                "bvae_seeds": make_seeds(run / "seeds", cli=cli_seeds, log=say),
                "bsdf_seed": str(bsdf.resolve()) if bsdf else None,
                "bsdf_skipped": None if bsdf else "no shared data folder with " + str(RGL_SEED),
                "model_seed": "default"}
        plan_path.write_text(json.dumps(plan, indent=1) + "\n")
    batches_path = run / "batches.jsonl"
    done = {json.loads(line)["batch"] for line in batches_path.read_text().splitlines()} \
        if batches_path.exists() else set()
    wanted = -(-inputs // plan["batch_size"])
    todo: queue.Queue[int] = queue.Queue()
    for batch in range(wanted):
        if batch not in done:
            todo.put(batch)
    say(f"{len(done)} batches done, {todo.qsize()} to run ({plan['batch_size']} inputs each, {workers} workers)")
    lock, started = threading.Lock(), time.monotonic()
    seeds = Seeds(run, plan)
    errors: list[BaseException] = []

    def work() -> None:
        pool = _Pool(run, memory_bytes)
        try:
            while True:
                try:
                    batch = todo.get_nowait()
                except queue.Empty:
                    return
                rows = pool.batch(batch, timeout, startup=180.0)
                line = _batch_line(batch, rows)
                with lock:
                    for row in rows:
                        if row["outcome"] in BUG_CLASSES or (row.get("seconds") or 0) > SLOW_SECONDS:
                            _save_example(run, seeds, plan["seed"], row)
                    with open(batches_path, "a", encoding="utf-8") as stream:
                        stream.write(json.dumps(line) + "\n")
                    done.add(batch)
                    bugs = sum(line["bugs"].values())
                    say(f"batch {batch} done ({len(done)}/{wanted}, {time.monotonic() - started:.0f} s): "
                        f"{dict(line['outcomes'])}{f', BUGS {bugs}' if bugs else ''}")
        except BaseException as error:  # noqa: BLE001 - reported by the caller
            errors.append(error)
        finally:
            pool.stop()

    threads = [threading.Thread(target=work, daemon=True) for _ in range(max(1, workers))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    if errors:
        raise errors[0]
    summary = campaign_summary(run)
    from brdfcodec.report.rows import stamp

    stamped = stamp([summary], study="fuzz", run=str(run))[0]
    (run / "summary.json").write_text(json.dumps(stamped, indent=1, sort_keys=False) + "\n", encoding="utf-8")
    return stamped


def _batch_line(batch: int, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """What a finished batch adds to the counts (and its bugs and slow inputs, each named)."""
    per: dict[str, Counter[str]] = defaultdict(Counter)
    for row in rows:
        key = f"{row.get('surface', '?')}/{row.get('seed', '?')}"
        per[key][row["outcome"]] += 1
        how = row.get("how", "?").split(" + ")[0]
        per[f"{row.get('surface', '?')} mutation/{how}"][row["outcome"]] += 1
    outcomes = Counter(row["outcome"] for row in rows)
    bugs = [row for row in rows if row["outcome"] in BUG_CLASSES]
    slow = [{"id": row["id"], "surface": row.get("surface"), "seconds": row["seconds"], "how": row.get("how")}
            for row in rows if (row.get("seconds") or 0) > SLOW_SECONDS and row["outcome"] not in BUG_CLASSES]
    return {"batch": batch, "inputs": len(rows), "outcomes": dict(outcomes), "per": {k: dict(v) for k, v in per.items()},
            "bugs": dict(Counter(row["outcome"] for row in bugs)), "bug_rows": bugs, "slow": slow}


def _save_example(run: Path, seeds: Seeds, campaign_seed: int, row: dict[str, Any]) -> None:
    """Write a bug's (or a slow input's) input and error under ``examples/CLASS/`` (at most 20 per class and
    surface, and one per distinct first error line)."""
    kind = row["outcome"] if row["outcome"] in BUG_CLASSES else "slow"
    folder = run / "examples" / kind.replace(", ", "-").replace(" ", "-")
    item = make_input(seeds, campaign_seed, row["id"])
    key = (row.get("error") or "").splitlines()[0] if row.get("error") else item["how"]
    index = folder / "index.jsonl"
    known = [json.loads(line) for line in index.read_text().splitlines()] if index.exists() else []
    same_surface = [k for k in known if k["surface"] == item["surface"]]
    if len(same_surface) >= 20 or any(k["key"] == key and k["surface"] == item["surface"] for k in known):
        return
    folder.mkdir(parents=True, exist_ok=True)
    if item["surface"] == "model":
        target = folder / f"model-{row['id']}"
        target.mkdir(exist_ok=True)
        for name, data in item["data"].items():
            if name == "model.json" or len(data) < 1 << 20:
                (target / name).write_bytes(data)
            else:  # a weight file: its header only; --replay writes the whole folder
                (target / f"{name}.header").write_bytes(data[: 8 + int.from_bytes(data[:8], "little")][:1 << 20])
        path = target
    else:
        suffix = ".bvae" if item["surface"] == "bvae" else "_rgb.bsdf"
        path = folder / f"{item['surface']}-{row['id']}{suffix}"
        path.write_bytes(item["data"])
    entry = {"id": row["id"], "surface": item["surface"], "seed": item["seed"], "how": item["how"],
             "outcome": row["outcome"], "seconds": row.get("seconds"), "key": key, "file": str(path.relative_to(run)),
             "error": row.get("error", "")}
    with open(index, "a", encoding="utf-8") as stream:
        stream.write(json.dumps(entry) + "\n")


def campaign_summary(run: Path) -> dict[str, Any]:
    """Counts of a run folder's finished batches: per outcome and surface, per seed, per mutation; the bugs."""
    lines = [json.loads(line) for line in (run / "batches.jsonl").read_text().splitlines()] \
        if (run / "batches.jsonl").exists() else []
    plan = json.loads((run / "plan.json").read_text())
    outcomes: Counter[str] = Counter()
    per: dict[str, Counter[str]] = defaultdict(Counter)
    bugs: list[dict[str, Any]] = []
    slow: list[dict[str, Any]] = []
    for line in lines:
        outcomes.update(line["outcomes"])
        for key, counts in line["per"].items():
            per[key].update(counts)
        bugs += line["bug_rows"]
        slow += line["slow"]
    surfaces: dict[str, Counter[str]] = defaultdict(Counter)
    for key, counts in per.items():
        if " mutation/" not in key:
            surfaces[key.split("/")[0]].update(counts)
    examples: dict[str, list[dict[str, Any]]] = {}
    for index in sorted((run / "examples").glob("*/index.jsonl")):
        examples[index.parent.name] = [json.loads(line) for line in index.read_text().splitlines()]
    return {
        "inputs": sum(line["inputs"] for line in lines),
        "batches": len(lines),
        "campaign_seed": plan["seed"],
        "batch_size": plan["batch_size"],
        "bsdf_skipped": plan.get("bsdf_skipped"),
        "bug_counts": {name: outcomes.get(name, 0) for name in BUG_CLASSES},
        "slow_inputs": len(slow),
        "outcomes": dict(sorted(outcomes.items())),
        "per_surface": {k: dict(sorted(v.items())) for k, v in sorted(surfaces.items())},
        "per_seed": {k: dict(sorted(v.items())) for k, v in sorted(per.items()) if " mutation/" not in k},
        "per_mutation": {k: dict(sorted(v.items())) for k, v in sorted(per.items()) if " mutation/" in k},
        "seeds": plan["bvae_seeds"],
        "bugs": [{k: v for k, v in bug.items() if k != "error"} | {"error": (bug.get("error") or "")[:300]}
                 for bug in bugs[:200]],
        "examples": examples,
    }


def replay(run: Path, input_id: str, target: Path) -> Path:
    """Write input ``input_id`` of a run folder's plan to ``target`` (a folder): the file or the model folder."""
    plan = json.loads((run / "plan.json").read_text())
    seeds = Seeds(run, plan)
    item = make_input(seeds, plan["seed"], input_id)
    path = write_input(item, target, seeds)
    return path


def register_fuzz(ops: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``bvae bench fuzz`` to the ``bench`` operations."""
    parser = ops.add_parser(
        "fuzz", help="fuzz campaign: mutated .bvae files, .bsdf headers and model folders; bugs counted and kept",
        description="Mutate valid inputs (.bvae files of every record kind made by the command line and the "
        "writer; the RGL file of the shared data; the shipped model folder) and run each mutant through what bvae "
        "info, bvae decompress and model loading run, in worker processes. Counts outcomes (accepted, refused with "
        "a typed error) and bugs (untyped errors, info accepting what decoding refuses, non-finite decodes, "
        "crashes, hangs); keeps each bug's input under OUTPUT/examples. A run folder resumes where it stopped.",
    )
    parser.add_argument("-o", "--output", type=Path, required=True, help="run folder (created; resumed if it exists)")
    parser.add_argument("--inputs", type=int, default=100_000, help="inputs in all (default 100000)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument("--batch-size", type=int, default=500, help="inputs per batch (default 500)")
    parser.add_argument("--seed", type=int, default=49, help="the campaign's random seed (default 49)")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds before an input counts as a hang")
    parser.add_argument("--writer-seeds-only", action="store_true",
                        help="no seeds from the command line (seconds instead of minutes to start)")
    parser.add_argument("--shared", type=Path, default=_default_shared(),
                        help="shared data folder holding data/rgl/paper_white_rgb.bsdf (default ../shared)")
    parser.add_argument("--replay", metavar="ID", help="only write input ID (B-I) of the run into --to and exit")
    parser.add_argument("--to", type=Path, help="with --replay: the folder to write it into")
    parser.set_defaults(handler=run_fuzz)


def _default_shared() -> Path | None:
    for candidate in (Path("../shared"), Path(__file__).resolve().parents[3] / "shared"):
        if candidate.is_dir():
            return candidate
    return None


def run_fuzz(args: argparse.Namespace) -> int:
    """``bvae bench fuzz``: run or resume a campaign (or replay one input); exit 1 when it found a bug."""
    if args.replay:
        if args.to is None:
            raise ValueError("--replay needs --to FOLDER")
        print(f"wrote {replay(args.output, args.replay, args.to)}")
        return 0
    if args.inputs < 1 or args.workers < 1 or args.batch_size < 1 or args.timeout <= 0:
        raise ValueError("--inputs, --workers, --batch-size and --timeout must be positive")
    log_path = args.output / "progress.log"
    args.output.mkdir(parents=True, exist_ok=True)

    def log(text: str) -> None:
        line = f"{time.strftime('%H:%M:%S')} {text}"
        print(line, flush=True)
        with open(log_path, "a", encoding="utf-8") as stream:
            stream.write(line + "\n")

    summary = run_campaign(args.output, inputs=args.inputs, batch_size=args.batch_size, workers=args.workers,
                           seed=args.seed, cli_seeds=not args.writer_seeds_only, shared=args.shared,
                           timeout=args.timeout, log=log)
    log(f"{summary['inputs']} inputs: bugs {summary['bug_counts']}, slow {summary['slow_inputs']}; "
        f"outcomes {summary['outcomes']}; wrote {args.output / 'summary.json'}")
    return 1 if any(summary["bug_counts"].values()) else 0


def _main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "--worker":
        return _worker(Path(argv[1]))
    print("usage: python -m brdfcodec.cli.fuzz_campaign --worker RUN (run by bvae bench fuzz)", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))

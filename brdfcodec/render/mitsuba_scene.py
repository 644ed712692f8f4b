"""Scenes for Mitsuba 3: which materials a scene references, loading it, rendering it, memory per material.

A scene is a Mitsuba XML file or a scene dictionary saved as JSON (the
dictionary :func:`mitsuba.load_dict` takes; transforms are written as
``{"look_at": {"origin": [...], "target": [...], "up": [...]}}``,
``{"translate": [...]}``, ``{"scale": s or [...]}``, ``{"matrix": 4×4}``, or
a list of these applied left to right; a ``path`` integrator is added when
the dictionary names none). Relative ``filename`` values are relative to the
scene file's folder.

:func:`scene_materials` reads a scene *without* Mitsuba, so that
``bvae extract --scene`` can keep only the materials a scene needs.
"""

from __future__ import annotations

import json
import os
import re
import xml.etree.ElementTree as ElementTree
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.errors import FileFormatError

__all__ = [
    "MaterialReference",
    "SceneFormatError",
    "load_scene",
    "material_memory",
    "render_scene",
    "scene_materials",
]

_PLUGINS = ("bvae", "merl")


class SceneFormatError(FileFormatError):
    """A scene file that cannot be read (bad XML or JSON, a bvae BSDF without a filename)."""


@dataclass(frozen=True)
class MaterialReference:
    """A ``bvae`` or ``merl`` BSDF named by a scene.

    Attributes
    ----------
    plugin : str
        ``"bvae"`` or ``"merl"``.
    filename : Path
        The file, resolved against the scene's folder.
    material : str or None
        The ``material`` property (None: the file's only material).
    """

    plugin: str
    filename: Path
    material: str | None


_PARAMETER = re.compile(r"\$(\w+)")


def _xml_references(path: Path) -> list[MaterialReference]:
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as error:
        raise SceneFormatError(path, f"not a valid Mitsuba XML scene ({error})") from None
    defaults = {d.get("name", ""): d.get("value", "") for d in root.iter("default")}

    def expand(text: str) -> str:
        return _PARAMETER.sub(lambda m: defaults.get(m.group(1), m.group(0)), text)

    references = []
    for bsdf in root.iter("bsdf"):
        plugin = bsdf.get("type")
        if plugin not in _PLUGINS:
            continue
        strings = {s.get("name"): expand(s.get("value", "")) for s in bsdf.findall("string")}
        if "filename" not in strings:
            raise SceneFormatError(path, f"a {plugin!r} BSDF has no filename")
        references.append(MaterialReference(plugin, (path.parent / strings["filename"]).resolve(),
                                            strings.get("material")))
    return references


def _walk(node: Any) -> Iterator[dict[str, Any]]:
    if isinstance(node, dict):
        yield node
        for value in node.values():
            yield from _walk(value)
    elif isinstance(node, list):
        for value in node:
            yield from _walk(value)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        scene = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise SceneFormatError(path, f"not a valid JSON scene ({error})") from None
    if not isinstance(scene, dict) or scene.get("type") != "scene":
        raise SceneFormatError(path, 'a JSON scene must be an object with "type": "scene"')
    return scene


def _json_references(path: Path, scene: dict[str, Any]) -> list[MaterialReference]:
    references = []
    for node in _walk(scene):
        if node.get("type") in _PLUGINS:
            if not isinstance(node.get("filename"), str):
                raise SceneFormatError(path, f"a {node['type']!r} BSDF has no filename")
            material = node.get("material")
            references.append(MaterialReference(node["type"], (path.parent / node["filename"]).resolve(),
                                                None if material is None else str(material)))
    return references


def _check_scene_path(path: str | os.PathLike[str]) -> Path:
    scene = Path(path)
    if not scene.is_file():
        raise FileNotFoundError(f"{scene}: no such scene file")
    if scene.suffix.lower() not in (".xml", ".json"):
        raise SceneFormatError(scene, "a scene must be a Mitsuba .xml file or a scene dictionary saved as .json")
    return scene


def scene_materials(path: str | os.PathLike[str]) -> list[MaterialReference]:
    """The ``bvae`` and ``merl`` BSDFs a scene names, in file order (duplicates kept).

    Parameters
    ----------
    path : path-like
        Mitsuba ``.xml`` scene or ``.json`` scene dictionary. XML ``$name``
        parameters are replaced by their ``<default>`` values.

    Returns
    -------
    list of MaterialReference

    Raises
    ------
    FileNotFoundError, SceneFormatError
    """
    scene = _check_scene_path(path)
    if scene.suffix.lower() == ".xml":
        return _xml_references(scene)
    return _json_references(scene, _read_json(scene))


def _transform(mi: Any, spec: Any) -> Any:
    if isinstance(spec, list) and spec and isinstance(spec[0], dict):
        result = mi.ScalarTransform4f()
        for part in spec:
            result = result @ _transform(mi, part)
        return result
    if isinstance(spec, list):
        return mi.ScalarTransform4f(spec)
    if "look_at" in spec:
        return mi.ScalarTransform4f().look_at(**spec["look_at"])
    if "translate" in spec:
        return mi.ScalarTransform4f().translate(spec["translate"])
    if "scale" in spec:
        return mi.ScalarTransform4f().scale(spec["scale"])
    if "rotate" in spec:
        return mi.ScalarTransform4f().rotate(spec["rotate"]["axis"], spec["rotate"]["angle"])
    if "matrix" in spec:
        return mi.ScalarTransform4f(spec["matrix"])
    raise ValueError(f"unknown transform {spec!r}")


def _prepare_dict(mi: Any, path: Path, node: Any) -> Any:
    if isinstance(node, list):
        return [_prepare_dict(mi, path, value) for value in node]
    if not isinstance(node, dict):
        return node
    result = {}
    for key, value in node.items():
        if key == "to_world":
            try:
                result[key] = _transform(mi, value)
            except (KeyError, TypeError, ValueError) as error:
                raise SceneFormatError(path, f"bad to_world {value!r} ({error})") from None
        elif key == "filename" and isinstance(value, str):
            result[key] = str((path.parent / value).resolve())
        else:
            result[key] = _prepare_dict(mi, path, value)
    return result


def load_scene(path: str | os.PathLike[str], **parameters: Any) -> Any:
    """Load a scene with the ``bvae`` and ``merl`` BSDFs registered in the current variant.

    Parameters
    ----------
    path : path-like
        Mitsuba ``.xml`` or ``.json`` scene dictionary.
    **parameters
        XML ``$name`` parameters (for example ``spp=16``); ignored for JSON.

    Returns
    -------
    mitsuba.Scene
    """
    from brdfcodec.render.mitsuba_bsdf import register

    scene = _check_scene_path(path)
    scene_materials(scene)  # readable, every bvae/merl BSDF names a file
    register()
    import mitsuba as mi

    if scene.suffix.lower() == ".xml":
        return mi.load_file(str(scene), **{k: str(v) for k, v in parameters.items()})
    scene_dict = _prepare_dict(mi, scene, _read_json(scene))
    plugins = mi.PluginManager.instance()
    if not any(isinstance(v, dict) and plugins.plugin_type(v.get("type", "")) == mi.ObjectType.Integrator
               for v in scene_dict.values()):
        scene_dict["default_integrator"] = {"type": "path"}
    return mi.load_dict(scene_dict)


def material_memory(scene: Any) -> dict[str, int]:
    """Table bytes per distinct material of a loaded scene (a material shared by shapes counts once)."""
    from brdfcodec.render.mitsuba_bsdf import material_of

    memory: dict[str, int] = {}
    seen: set[int] = set()
    for shape in scene.shapes():
        tables = material_of(shape.bsdf())
        if tables is None:
            continue
        if id(tables) not in seen:
            seen.add(id(tables))
            memory[f"{tables.name} ({tables.precision})"] = tables.nbytes
    return memory


def render_scene(
    path: str | os.PathLike[str], *, spp: int | None = None, seed: int = 0, **parameters: Any
) -> tuple[np.ndarray, Any]:
    """Load and render a scene in the current variant: (linear RGB image (H, W, 3) float32, scene).

    ``spp`` overrides the scene's sample count; ``parameters`` are XML ``$name`` parameters.
    """
    import mitsuba as mi

    scene = load_scene(path, **parameters)
    image = mi.render(scene, spp=spp or 0, seed=seed)
    return np.asarray(image, dtype=np.float32)[..., :3], scene


def render_command(args: Any) -> int:
    """``bvae render --mitsuba SCENE -o OUT`` (called by :mod:`brdfcodec.cli.render_command`)."""
    import time

    from brdfcodec.io.atomic import check_output_path
    from brdfcodec.render.images import write_image
    from brdfcodec.runtime.mitsuba import set_variant

    if args.input is not None:
        raise ValueError("--mitsuba renders a scene: give the scene only, not IN as well")
    if args.output.suffix.lower() not in (".png", ".exr"):
        raise ValueError(f"{args.output}: the output must be .png or .exr")
    if args.spp is not None and not 1 <= args.spp <= 1 << 16:
        raise ValueError("--spp must be between 1 and 65536")
    check_output_path(args.output, overwrite=args.force)
    _check_scene_path(args.mitsuba)
    variant = set_variant(args.variant)
    start = time.perf_counter()
    try:
        image, scene = render_scene(args.mitsuba, spp=args.spp)
    except Exception as error:  # noqa: BLE001 - Mitsuba reports plug-in and XML errors as plain exceptions
        raise SceneFormatError(args.mitsuba, str(error).strip().splitlines()[-1]) from None
    elapsed = time.perf_counter() - start
    if not np.isfinite(image).all():
        raise ValueError(f"{args.mitsuba}: the render holds non-finite pixels")
    write_image(args.output, image, exposure=args.exposure, overwrite=args.force)
    memory = material_memory(scene)
    height, width = image.shape[:2]
    print(f"wrote {args.output} ({width}x{height}, {variant}, {elapsed:.2f} s including loading)")
    for name, size in memory.items():
        print(f"  {name}: {size / 1e6:.1f} MB")
    return 0


def scene_selection(
    scene: str | os.PathLike[str], library: Path | None, extra: list[str] | None
) -> tuple[Path, list[str]]:
    """(library, materials) that ``bvae extract --scene`` keeps: those the scene takes from the library.

    Parameters
    ----------
    scene : path-like
        The scene.
    library : Path or None
        The library; None means the one ``.bvae`` file the scene's ``bvae`` BSDFs name.
    extra : list of str or None
        ``--material`` names to keep as well.

    Returns
    -------
    (Path, list of str)
        The library and its referenced materials, each once, in scene order.
    """
    from brdfcodec.format.bvae import read_header

    references = [r for r in scene_materials(scene) if r.plugin == "bvae" and r.filename.suffix.lower() != ".binary"]
    if library is None:
        files = sorted({r.filename for r in references})
        if len(files) != 1:
            raise SceneFormatError(scene, f"names {len(files)} .bvae files ({', '.join(map(str, files)) or 'none'}); "
                                   "give the library as LIB.bvae")
        library = files[0]
    target = Path(library).resolve()
    chosen = [r for r in references if r.filename == target]
    if not chosen:
        raise SceneFormatError(scene, f"takes no material from {library}")
    header = read_header(library)
    names: list[str] = []
    for reference in chosen:
        name = reference.material
        if name is None:
            if len(header.names) != 1:
                raise SceneFormatError(scene, f"a bvae BSDF names {library} without a material, and it holds "
                                       f"{len(header.names)}")
            name = header.names[0]
        if name not in header.names:
            raise SceneFormatError(scene, f"material {name!r} is not in {library}")
        if name not in names:
            names.append(name)
    names += [name for name in extra or [] if name not in names]
    return Path(library), names

"""Reading stiffness maps from files: an ``.npz`` or a manifest naming one ``.csv``/``.npy`` matrix per depth (the
layouts are described in :mod:`studyctl.models.stiffness_map`), with units converted and every field checked."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError, NotFoundError
from studyctl.inputs import loads_json, read_text
from studyctl.models.stiffness_map import (
    _FORCE_UNITS,
    _LENGTH_UNITS,
    FORMAT_KEY,
    FORMAT_VERSION,
    StiffnessMap,
)
from studyctl.yamlmarks import load_plain


def load_stiffness_map(path: str | Path) -> StiffnessMap:
    """Load a stiffness map from an ``.npz`` file or a manifest (``.yaml``, ``.yml``, ``.json``).

    Parameters
    ----------
    path
        The ``.npz`` file, or the manifest naming one ``.csv``/``.npy`` matrix per depth (paths relative to
        the manifest's folder). See the module docstring for both layouts.

    Returns
    -------
    StiffnessMap
        Forces converted to newtons, lengths to mm, arrays in (depth, x, y) order.

    Raises
    ------
    NotFoundError
        The file or a matrix file it names does not exist.
    ModelParameterError
        Anything malformed; the message names the file and the field.
    """
    path = Path(path)
    if not path.is_file():
        raise NotFoundError(f"stiffness map {path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return _load_npz(path)
    if suffix in (".yaml", ".yml", ".json"):
        return _load_manifest(path)
    raise ModelParameterError(
        f"stiffness map {path}: unknown file type {suffix!r}; give an .npz file or a .yaml/.json manifest "
        "that names one .csv/.npy matrix per depth"
    )


def _unit_factor(value: Any, table: dict[str, float], field_name: str, where: str) -> float:
    if value not in table:
        raise ModelParameterError(
            f"stiffness map {where}: field {field_name!r} is {value!r}; allowed: {', '.join(table)}"
        )
    return table[value]


def _axis_order(value: Any, where: str) -> str:
    if value not in ("xy", "yx"):
        raise ModelParameterError(
            f"stiffness map {where}: field 'axis_order' is {value!r}; use 'xy' (rows along x) or 'yx' (rows along y)"
        )
    return value


def _scalar(value: Any, field_name: str, where: str) -> float:
    try:
        out = float(np.asarray(value).reshape(()))
    except (TypeError, ValueError):
        raise ModelParameterError(
            f"stiffness map {where}: field {field_name!r} is {value!r}; expected a number"
        ) from None
    return out


def _load_npz(path: Path) -> StiffnessMap:
    where = str(path)
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ModelParameterError(f"stiffness map {where}: not a readable .npz file ({exc})") from None
    with data:
        keys = set(data.files)
        for required in ("normal", "depths", "dx", "dy"):
            if required not in keys:
                raise ModelParameterError(
                    f"stiffness map {where}: field {required!r} is missing; an .npz map needs arrays "
                    "normal, depths, dx, dy (optional horizontal, x0, y0, force_unit, length_unit, axis_order)"
                )
        fu = _unit_factor(str(data["force_unit"]) if "force_unit" in keys else "N", _FORCE_UNITS, "force_unit", where)
        lu = _unit_factor(
            str(data["length_unit"]) if "length_unit" in keys else "mm", _LENGTH_UNITS, "length_unit", where
        )
        order = _axis_order(str(data["axis_order"]) if "axis_order" in keys else "xy", where)
        normal = np.array(data["normal"], dtype=float)
        horizontal = np.array(data["horizontal"], dtype=float) if "horizontal" in keys else None
        depths = np.array(data["depths"], dtype=float)
        dx = _scalar(data["dx"], "dx", where)
        dy = _scalar(data["dy"], "dy", where)
        x0 = _scalar(data["x0"], "x0", where) if "x0" in keys else 0.0
        y0 = _scalar(data["y0"], "y0", where) if "y0" in keys else 0.0
    if order == "yx":
        normal = np.swapaxes(normal, -1, -2)
        horizontal = None if horizontal is None else np.swapaxes(horizontal, -1, -2)
    return StiffnessMap.from_arrays(
        normal * fu,
        depths * lu,
        dx_mm=dx * lu,
        dy_mm=dy * lu,
        horizontal=None if horizontal is None else horizontal * fu,
        x0_mm=x0 * lu,
        y0_mm=y0 * lu,
        source=where,
    )


def _read_manifest(path: Path) -> dict[str, Any]:

    text = read_text(path, "stiffness map manifest", error=ModelParameterError)
    try:
        doc = loads_json(text) if path.suffix.lower() == ".json" else load_plain(text, str(path))
    except Exception as exc:  # yaml and json raise many types; all mean "not parseable"
        raise ModelParameterError(f"stiffness map {path}: cannot parse the manifest ({exc})".splitlines()[0]) from None
    if not isinstance(doc, dict):
        raise ModelParameterError(f"stiffness map {path}: the manifest must be a mapping with {FORMAT_KEY}: 1 …")
    return doc


def _load_manifest(path: Path) -> StiffnessMap:
    where = str(path)
    doc = _read_manifest(path)
    if doc.get(FORMAT_KEY) != FORMAT_VERSION:
        raise ModelParameterError(
            f"stiffness map {where}: field {FORMAT_KEY!r} is {doc.get(FORMAT_KEY)!r}; expected {FORMAT_VERSION}"
        )
    known = {FORMAT_KEY, "units", "grid", "axis_order", "depths", "normal", "horizontal", "notes"}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise ModelParameterError(
            f"stiffness map {where}: unknown field {unknown[0]!r}; allowed: {', '.join(sorted(known))}"
        )
    units = doc.get("units") or {}
    if not isinstance(units, dict):
        raise ModelParameterError(
            f"stiffness map {where}: field 'units' must be a mapping like {{force: N, length: mm}}"
        )
    fu = _unit_factor(units.get("force", "N"), _FORCE_UNITS, "units.force", where)
    lu = _unit_factor(units.get("length", "mm"), _LENGTH_UNITS, "units.length", where)
    grid = doc.get("grid")
    if not isinstance(grid, dict) or "dx" not in grid or "dy" not in grid:
        raise ModelParameterError(
            f"stiffness map {where}: field 'grid' must give dx and dy (and optionally x0, y0) in the length unit"
        )
    order = _axis_order(doc.get("axis_order", "xy"), where)
    depths = doc.get("depths")
    if not isinstance(depths, list) or not depths:
        raise ModelParameterError(f"stiffness map {where}: field 'depths' must be a non-empty list of depths")
    stacks: dict[str, np.ndarray | None] = {"normal": None, "horizontal": None}
    for name in ("normal", "horizontal"):
        files = doc.get(name)
        if files is None:
            if name == "normal":
                raise ModelParameterError(
                    f"stiffness map {where}: field 'normal' is missing; list one matrix per depth"
                )
            continue
        if not isinstance(files, list) or len(files) != len(depths):
            count = len(files) if isinstance(files, list) else "not a list"
            raise ModelParameterError(
                f"stiffness map {where}: field {name!r} names {count} files for {len(depths)} depths; "
                "give exactly one matrix file per depth, in the order of 'depths'"
            )
        matrices = []
        first_shape: tuple[int, ...] | None = None
        first_file = ""
        for k, fname in enumerate(files):
            mpath = path.parent / str(fname)
            matrix = _read_matrix(mpath, name)
            if order == "yx":
                matrix = matrix.T
            bad = ~np.isfinite(matrix)
            if bad.any():
                i, j = (int(v) for v in np.argwhere(bad)[0])
                raise ModelParameterError(
                    f"stiffness map {mpath}: field {name!r} (depth {depths[k]}) has {int(bad.sum())} NaN/empty cells, "
                    f"first at row {i}, column {j}; a measured map must be complete: re-measure or fill those cells"
                )
            if first_shape is None:
                first_shape, first_file = matrix.shape, str(fname)
            elif matrix.shape != first_shape:
                raise ModelParameterError(
                    f"stiffness map {mpath}: field {name!r} (depth {depths[k]}) is {matrix.shape[0]} × "
                    f"{matrix.shape[1]} but {first_file} is {first_shape[0]} × {first_shape[1]}; every depth "
                    "must be measured on the same grid"
                )
            matrices.append(matrix)
        stacks[name] = np.stack(matrices)
    normal = stacks["normal"]
    horizontal = stacks["horizontal"]
    if normal is None:  # unreachable: a missing 'normal' was refused above; keeps type checkers honest
        raise ModelParameterError(f"stiffness map {where}: field 'normal' is missing")
    if horizontal is not None and horizontal.shape != normal.shape:
        raise ModelParameterError(
            f"stiffness map {where}: field 'horizontal' matrices are {horizontal.shape[1]} × {horizontal.shape[2]} "
            f"but 'normal' ones are {normal.shape[1]} × {normal.shape[2]}; both must use the same grid"
        )
    try:
        depth_values = [float(d) for d in depths]
    except (TypeError, ValueError):
        raise ModelParameterError(
            f"stiffness map {where}: field 'depths' is {depths!r}; depths must be numbers"
        ) from None
    grid_values = {}
    for key in ("dx", "dy", "x0", "y0"):
        raw = grid.get(key, 0.0)
        if isinstance(raw, bool) or not isinstance(raw, int | float):
            raise ModelParameterError(f"stiffness map {where}: field 'grid.{key}' is {raw!r}; expected a number")
        grid_values[key] = float(raw) * lu
    return StiffnessMap.from_arrays(
        normal * fu,
        np.array(depth_values) * lu,
        dx_mm=grid_values["dx"],
        dy_mm=grid_values["dy"],
        horizontal=None if horizontal is None else horizontal * fu,
        x0_mm=grid_values["x0"],
        y0_mm=grid_values["y0"],
        source=where,
        notes=tuple(str(n) for n in doc.get("notes", []) or []),
    )


def _read_matrix(path: Path, field_name: str) -> np.ndarray:
    if not path.is_file():
        raise NotFoundError(f"stiffness map {path}: no such file (named in field {field_name!r} of the manifest)")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise ModelParameterError(f"stiffness map {path}: not a readable .npy file ({exc})") from None
        arr = np.asarray(arr, dtype=float)
        if arr.ndim != 2:
            raise ModelParameterError(
                f"stiffness map {path}: field {field_name!r} has shape {arr.shape}; expected one 2-D matrix per file"
            )
        return arr
    if suffix in (".csv", ".txt"):
        return _read_csv_matrix(path, field_name)
    raise ModelParameterError(f"stiffness map {path}: unknown matrix file type {suffix!r}; use .csv or .npy")


def _read_csv_matrix(path: Path, field_name: str) -> np.ndarray:
    """Comma- or whitespace-separated numbers; ``#`` comments; empty cells and ``nan`` become NaN."""
    rows: list[list[float]] = []
    width: int | None = None
    with path.open(newline="") as handle:
        for lineno, line in enumerate(handle, start=1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            cells = next(csv.reader([text])) if "," in text else text.split()
            values = []
            for col, cell in enumerate(cells, start=1):
                cell = cell.strip()
                if cell == "" or cell.lower() in ("nan", "na"):
                    values.append(math.nan)
                    continue
                try:
                    values.append(float(cell))
                except ValueError:
                    raise ModelParameterError(
                        f"stiffness map {path}:{lineno}: field {field_name!r} column {col} is {cell!r}; "
                        "expected a number (force)"
                    ) from None
            if width is None:
                width = len(values)
            elif len(values) != width:
                raise ModelParameterError(
                    f"stiffness map {path}:{lineno}: field {field_name!r} row has {len(values)} cells but the first "
                    f"row has {width}; the matrix must be rectangular"
                )
            rows.append(values)
    if not rows:
        raise ModelParameterError(f"stiffness map {path}: field {field_name!r} file holds no numbers")
    return np.array(rows, dtype=float)

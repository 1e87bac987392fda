"""Measured stiffness maps: normal and horizontal reaction-force matrices per indentation depth.

A rolling-indentation scan (seeds 002 and 003) gives, for each constant indentation depth, a matrix of
reaction forces over a regular grid of surface positions. :class:`StiffnessMap` holds the stack of those
matrices with the metadata needed to use them: grid spacing and origin (mm), the depths (mm, strictly
increasing) and the unit conversion already applied (forces are newtons after loading).

Array layout: ``normal_n[k, i, j]`` is the normal force at depth ``depths_mm[k]`` and surface position
``x = x0_mm + i * dx_mm``, ``y = y0_mm + j * dy_mm``; the paper's "159 × 59" matrices are ``nx × ny``.

Two file layouts are read (by :func:`studyctl.models.stiffness_map_files.load_stiffness_map`):

* one ``.npz`` holding arrays ``normal`` (depths × nx × ny), optional ``horizontal``, ``depths`` and the
  scalars ``dx``, ``dy`` (optional ``x0``, ``y0``, ``force_unit``, ``length_unit``, ``axis_order``);
* a manifest (``.yaml``/``.yml``/``.json``) naming one matrix file per depth (``.csv`` or ``.npy``)::

      studyctl_stiffness_map: 1
      units: {force: N, length: mm}          # force N or mN; length mm or m
      grid: {dx: 0.766, dy: 2.0, x0: 0.0, y0: 2.0}
      axis_order: xy                         # rows run along x (default); "yx" if rows run along y
      depths: [2, 3, 4, 5, 6, 7]
      normal: [normal_2mm.csv, normal_3mm.csv, ...]
      horizontal: [horizontal_2mm.csv, ...]  # optional

Negative cells are accepted (a force sensor's offset noise around zero); renderers clamp forces to ≥ 0.
NaN or infinite cells, ragged or mismatched shapes and non-increasing depths are refused with a
:class:`~studyctl.errors.ModelParameterError` that names the file and the field.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from studyctl.errors import ModelParameterError

FORMAT_KEY = "studyctl_stiffness_map"
FORMAT_VERSION = 1
_FORCE_UNITS = {"N": 1.0, "mN": 1e-3}
_LENGTH_UNITS = {"mm": 1.0, "m": 1e3}


@dataclass(frozen=True, eq=False)
class StiffnessMap:
    """Reaction-force matrices over a regular (x, y) grid, one per indentation depth.

    Build with :meth:`from_arrays` (validates) or the loaders; arrays are stored read-only.

    Attributes
    ----------
    normal_n : ndarray, shape (n_depths, nx, ny)
        Normal reaction force in newtons.
    horizontal_n : ndarray or None
        Horizontal (rolling) reaction force in newtons, same shape, when it was measured.
    depths_mm : ndarray, shape (n_depths,)
        Indentation depths in mm, strictly increasing and positive.
    dx_mm, dy_mm : float
        Grid spacing along x and y in mm.
    x0_mm, y0_mm : float
        Position of node (0, 0) in mm.
    source : str
        Where the data came from (file path or generator description).
    """

    normal_n: np.ndarray
    horizontal_n: np.ndarray | None
    depths_mm: np.ndarray
    dx_mm: float
    dy_mm: float
    x0_mm: float = 0.0
    y0_mm: float = 0.0
    source: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)

    @classmethod
    def from_arrays(
        cls,
        normal: Any,
        depths: Any,
        *,
        dx_mm: float,
        dy_mm: float,
        horizontal: Any | None = None,
        x0_mm: float = 0.0,
        y0_mm: float = 0.0,
        source: str = "arrays",
        notes: tuple[str, ...] = (),
    ) -> StiffnessMap:
        """Validate arrays (forces in N, lengths in mm) and build a map.

        Raises
        ------
        ModelParameterError
            Shapes that are not (n_depths, nx, ny) or disagree, NaN/inf cells, depths that are not
            strictly increasing and positive, non-positive spacing. The message names ``source``.
        """
        normal_arr = _as_stack(normal, "normal", source)
        depths_arr = _check_depths(depths, normal_arr.shape[0], source)
        _check_finite(normal_arr, "normal", source, depths_arr)
        horizontal_arr = None
        if horizontal is not None:
            horizontal_arr = _as_stack(horizontal, "horizontal", source)
            if horizontal_arr.shape != normal_arr.shape:
                raise ModelParameterError(
                    f"stiffness map {source}: field 'horizontal' has shape {horizontal_arr.shape} but 'normal' has "
                    f"{normal_arr.shape}; both need one nx × ny matrix per depth on the same grid"
                )
            _check_finite(horizontal_arr, "horizontal", source, depths_arr)
        for name, value in (("dx", dx_mm), ("dy", dy_mm)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ModelParameterError(
                    f"stiffness map {source}: field 'grid.{name}' is {value!r}; it must be a positive spacing in mm"
                )
        for name, value in (("x0", x0_mm), ("y0", y0_mm)):
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ModelParameterError(
                    f"stiffness map {source}: field 'grid.{name}' is {value!r}; it must be a finite position in mm"
                )
        for arr in (normal_arr, depths_arr, horizontal_arr):
            if arr is not None:
                arr.setflags(write=False)
        return cls(
            normal_n=normal_arr,
            horizontal_n=horizontal_arr,
            depths_mm=depths_arr,
            dx_mm=float(dx_mm),
            dy_mm=float(dy_mm),
            x0_mm=float(x0_mm),
            y0_mm=float(y0_mm),
            source=source,
            notes=tuple(notes),
        )

    @property
    def shape(self) -> tuple[int, int, int]:
        """(n_depths, nx, ny)."""
        return tuple(self.normal_n.shape)  # type: ignore[return-value]

    @property
    def xs_mm(self) -> np.ndarray:
        return self.x0_mm + self.dx_mm * np.arange(self.normal_n.shape[1])

    @property
    def ys_mm(self) -> np.ndarray:
        return self.y0_mm + self.dy_mm * np.arange(self.normal_n.shape[2])

    @property
    def extent_mm(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the mapped area; outside it the map says nothing."""
        _, nx, ny = self.normal_n.shape
        return (self.x0_mm, self.x0_mm + (nx - 1) * self.dx_mm, self.y0_mm, self.y0_mm + (ny - 1) * self.dy_mm)

    def horizontal_or_zero(self) -> np.ndarray:
        """Horizontal forces, or zeros when the map has none (seed 002 recorded normal force only)."""
        return self.horizontal_n if self.horizontal_n is not None else np.zeros_like(self.normal_n)

    def subsample(self, step: int) -> StiffnessMap:
        """A coarser table over the same area, about every ``step``-th node along x and y (depths kept).

        The coarse grid has ``ceil((n − 1)/step) + 1`` nodes per axis spanning the full extent, so the mapped
        area does not shrink; where ``step`` divides ``n − 1`` its nodes are exactly every ``step``-th original
        node, otherwise their values are linear interpolations of the original table. These are the cheaper
        tables of ``studyctl bench render``.
        """
        if not isinstance(step, int) or isinstance(step, bool) or step < 1:
            raise ModelParameterError(f"subsample step {step!r}: must be a positive integer")
        if step == 1:
            return self
        _, nx, ny = self.normal_n.shape
        mx, my = math.ceil((nx - 1) / step) + 1, math.ceil((ny - 1) / step) + 1
        ux = np.linspace(0.0, nx - 1, mx)  # coarse node positions in original index units
        uy = np.linspace(0.0, ny - 1, my)

        def resample(stack: np.ndarray) -> np.ndarray:
            i = np.minimum(ux.astype(int), nx - 2)
            ti = ux - i
            j = np.minimum(uy.astype(int), ny - 2)
            tj = uy - j
            a = stack[:, i, :] * (1 - ti)[None, :, None] + stack[:, i + 1, :] * ti[None, :, None]
            return a[:, :, j] * (1 - tj)[None, None, :] + a[:, :, j + 1] * tj[None, None, :]

        return StiffnessMap.from_arrays(
            resample(self.normal_n),
            self.depths_mm.copy(),
            dx_mm=self.dx_mm * (nx - 1) / (mx - 1),
            dy_mm=self.dy_mm * (ny - 1) / (my - 1),
            horizontal=None if self.horizontal_n is None else resample(self.horizontal_n),
            x0_mm=self.x0_mm,
            y0_mm=self.y0_mm,
            source=f"{self.source} (coarsened ×{step})",
            notes=self.notes,
        )

    def to_frame(self) -> pd.DataFrame:
        """Long table: columns depth_mm, ix, iy, x_mm, y_mm, normal_n, horizontal_n (NaN when not measured)."""
        nd, nx, ny = self.normal_n.shape
        k, i, j = np.meshgrid(np.arange(nd), np.arange(nx), np.arange(ny), indexing="ij")
        h = self.horizontal_n if self.horizontal_n is not None else np.full(self.normal_n.shape, np.nan)
        return pd.DataFrame(
            {
                "depth_mm": self.depths_mm[k.ravel()],
                "ix": i.ravel(),
                "iy": j.ravel(),
                "x_mm": self.x0_mm + self.dx_mm * i.ravel(),
                "y_mm": self.y0_mm + self.dy_mm * j.ravel(),
                "normal_n": self.normal_n.ravel(),
                "horizontal_n": h.ravel(),
            }
        )

    def save_npz(self, path: str | Path) -> Path:
        """Write the single-file layout that :func:`~studyctl.models.stiffness_map_files.load_stiffness_map` reads
        back exactly."""
        path = Path(path)
        arrays: dict[str, Any] = {
            "normal": self.normal_n,
            "depths": self.depths_mm,
            "dx": np.float64(self.dx_mm),
            "dy": np.float64(self.dy_mm),
            "x0": np.float64(self.x0_mm),
            "y0": np.float64(self.y0_mm),
            "force_unit": np.str_("N"),
            "length_unit": np.str_("mm"),
            "axis_order": np.str_("xy"),
            "source": np.str_(self.source),
        }
        if self.horizontal_n is not None:
            arrays["horizontal"] = self.horizontal_n
        np.savez(path, **arrays)
        return path

    def save_manifest(self, path: str | Path, matrix_format: str = "csv") -> Path:
        """Write a JSON/YAML manifest plus one ``.csv`` or ``.npy`` matrix per depth and field beside it."""
        path = Path(path)
        if matrix_format not in ("csv", "npy"):
            raise ModelParameterError(f"matrix_format {matrix_format!r}: use 'csv' or 'npy'")
        manifest: dict[str, Any] = {
            FORMAT_KEY: FORMAT_VERSION,
            "units": {"force": "N", "length": "mm"},
            "grid": {"dx": self.dx_mm, "dy": self.dy_mm, "x0": self.x0_mm, "y0": self.y0_mm},
            "axis_order": "xy",
            "depths": [float(d) for d in self.depths_mm],
        }
        fields = [("normal", self.normal_n)]
        if self.horizontal_n is not None:
            fields.append(("horizontal", self.horizontal_n))
        for name, stack in fields:
            names = []
            for depth, matrix in zip(self.depths_mm, stack, strict=True):
                fname = f"{path.stem}_{name}_{_depth_tag(depth)}.{matrix_format}"
                if matrix_format == "csv":
                    np.savetxt(path.parent / fname, matrix, delimiter=",", fmt="%.9g")
                else:
                    np.save(path.parent / fname, matrix)
                names.append(fname)
            manifest[name] = names
        if path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            path.write_text(yaml.safe_dump(manifest, sort_keys=False))
        else:
            path.write_text(json.dumps(manifest, indent=2))
        return path


def _depth_tag(depth: float) -> str:
    return f"{depth:g}mm".replace(".", "p")


def _as_stack(value: Any, name: str, source: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ModelParameterError(
            f"stiffness map {source}: field {name!r} is not a numeric array ({exc}); "
            "give one nx × ny matrix of forces per depth"
        ) from None
    if arr.ndim == 2:
        arr = arr[None, :, :]
    if arr.ndim != 3 or min(arr.shape) < 1:
        raise ModelParameterError(
            f"stiffness map {source}: field {name!r} has shape {arr.shape}; expected (n_depths, nx, ny) "
            "with at least one depth and one node along each axis"
        )
    if arr.shape[1] < 2 or arr.shape[2] < 2:
        raise ModelParameterError(
            f"stiffness map {source}: field {name!r} has {arr.shape[1]} × {arr.shape[2]} nodes per depth; "
            "interpolation needs at least 2 × 2"
        )
    return arr


def _check_depths(depths: Any, n_expected: int, source: str) -> np.ndarray:
    try:
        arr = np.array(depths, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ModelParameterError(
            f"stiffness map {source}: field 'depths' is {depths!r}; give a list of indentation depths"
        ) from None
    if arr.size != n_expected:
        raise ModelParameterError(
            f"stiffness map {source}: field 'depths' lists {arr.size} depths but there are {n_expected} force "
            "matrices; give exactly one depth per matrix"
        )
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ModelParameterError(
            f"stiffness map {source}: field 'depths' is {arr.tolist()}; every depth must be a finite positive "
            "indentation"
        )
    if arr.size > 1 and np.any(np.diff(arr) <= 0):
        k = int(np.argmax(np.diff(arr) <= 0))
        raise ModelParameterError(
            f"stiffness map {source}: field 'depths' is not strictly increasing ({arr[k]:g} then {arr[k + 1]:g} "
            f"in {arr.tolist()}); list depths in increasing order with their matrices in the same order"
        )
    return arr


def _check_finite(stack: np.ndarray, name: str, source: str, depths: np.ndarray) -> None:
    bad = ~np.isfinite(stack)
    if bad.any():
        k, i, j = (int(v) for v in np.argwhere(bad)[0])
        raise ModelParameterError(
            f"stiffness map {source}: field {name!r} has {int(bad.sum())} NaN/infinite cells, first at depth "
            f"{depths[k]:g} mm, row {i}, column {j}; a measured map must be complete: re-measure or fill those cells"
        )


# ----------------------------------------------------------------------------------------------- loading

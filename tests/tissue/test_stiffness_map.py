"""Stiffness maps: loading from NPZ and from manifests of CSV/NPY matrices, units, and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from studyctl.errors import ModelParameterError, NotFoundError
from studyctl.models.stiffness_map import StiffnessMap
from studyctl.models.stiffness_map_files import load_stiffness_map


def _map(nd=3, nx=5, ny=4, horizontal=True) -> StiffnessMap:
    rng = np.random.default_rng(1)
    normal = rng.uniform(0.1, 2.0, (nd, nx, ny))
    return StiffnessMap.from_arrays(
        normal,
        [2.0, 4.0, 6.0][:nd],
        dx_mm=0.5,
        dy_mm=2.0,
        horizontal=normal * 0.1 if horizontal else None,
        x0_mm=1.0,
        y0_mm=-3.0,
    )


def test_npz_round_trip(tmp_path):
    m = _map()
    back = load_stiffness_map(m.save_npz(tmp_path / "map.npz"))
    np.testing.assert_array_equal(back.normal_n, m.normal_n)
    np.testing.assert_array_equal(back.horizontal_n, m.horizontal_n)
    np.testing.assert_array_equal(back.depths_mm, m.depths_mm)
    assert (back.dx_mm, back.dy_mm, back.x0_mm, back.y0_mm) == (0.5, 2.0, 1.0, -3.0)
    assert back.extent_mm == (1.0, 3.0, -3.0, 3.0)


@pytest.mark.parametrize("suffix,fmt", [(".json", "csv"), (".yaml", "npy"), (".yml", "csv")])
def test_manifest_round_trip(tmp_path, suffix, fmt):
    m = _map()
    back = load_stiffness_map(m.save_manifest(tmp_path / f"map{suffix}", matrix_format=fmt))
    np.testing.assert_allclose(back.normal_n, m.normal_n, rtol=1e-8)
    np.testing.assert_allclose(back.horizontal_n, m.horizontal_n, rtol=1e-8)
    assert back.shape == (3, 5, 4)


def test_units_and_axis_order_are_converted(tmp_path):
    m = _map(horizontal=False)
    files = []
    for k, matrix in enumerate(m.normal_n):
        np.savetxt(tmp_path / f"n{k}.csv", matrix.T * 1000.0, delimiter=",")  # mN, rows along y
        files.append(f"n{k}.csv")
    manifest = {
        "studyctl_stiffness_map": 1,
        "units": {"force": "mN", "length": "m"},
        "grid": {"dx": 0.0005, "dy": 0.002, "x0": 0.001, "y0": -0.003},
        "axis_order": "yx",
        "depths": [0.002, 0.004, 0.006],
        "normal": files,
    }
    (tmp_path / "m.json").write_text(json.dumps(manifest))
    back = load_stiffness_map(tmp_path / "m.json")
    np.testing.assert_allclose(back.normal_n, m.normal_n, rtol=1e-9)
    np.testing.assert_allclose(back.depths_mm, [2.0, 4.0, 6.0])
    assert back.dx_mm == pytest.approx(0.5) and back.y0_mm == pytest.approx(-3.0)
    assert back.horizontal_n is None
    np.testing.assert_array_equal(back.horizontal_or_zero(), np.zeros_like(back.normal_n))


def _manifest(tmp_path, matrices, depths=(2, 4, 6), **extra):
    names = []
    for k, matrix in enumerate(matrices):
        path = tmp_path / f"normal_{k}.csv"
        if isinstance(matrix, str):
            path.write_text(matrix)
        else:
            np.savetxt(path, matrix, delimiter=",")
        names.append(path.name)
    doc = {"studyctl_stiffness_map": 1, "grid": {"dx": 1.0, "dy": 1.0}, "depths": list(depths), "normal": names}
    doc.update(extra)
    (tmp_path / "map.json").write_text(json.dumps(doc))
    return tmp_path / "map.json"


def test_inconsistent_shapes_name_the_file_and_field(tmp_path):
    path = _manifest(tmp_path, [np.ones((4, 3)), np.ones((4, 3)), np.ones((5, 3))])
    with pytest.raises(
        ModelParameterError, match=r"normal_2\.csv: field 'normal' \(depth 6\) is 5 × 3 but normal_0\.csv is 4 × 3"
    ):
        load_stiffness_map(path)


def test_ragged_csv_row_names_the_line(tmp_path):
    path = _manifest(tmp_path, ["1,2,3\n4,5\n", np.ones((2, 3)), np.ones((2, 3))])
    with pytest.raises(
        ModelParameterError, match=r"normal_0\.csv:2: field 'normal' row has 2 cells but the first row has 3"
    ):
        load_stiffness_map(path)


def test_nan_cell_names_file_field_and_cell(tmp_path):
    path = _manifest(tmp_path, [np.ones((3, 3)), "1,1,1\n1,,1\n1,1,1\n", np.ones((3, 3))])
    with pytest.raises(ModelParameterError) as err:
        load_stiffness_map(path)
    msg = str(err.value)
    assert "normal_1.csv" in msg and "field 'normal'" in msg and "row 1, column 1" in msg


def test_nan_in_npz_names_the_file(tmp_path):
    normal = np.ones((2, 3, 3))
    normal[1, 2, 0] = np.nan
    np.savez(tmp_path / "bad.npz", normal=normal, depths=[2.0, 3.0], dx=1.0, dy=1.0)
    with pytest.raises(
        ModelParameterError,
        match=r"bad\.npz: field 'normal' has 1 NaN/infinite cells, first at depth 3 mm, row 2, column 0",
    ):
        load_stiffness_map(tmp_path / "bad.npz")


@pytest.mark.parametrize("depths", [(2, 6, 4), (2, 2, 4), (6, 4, 2)])
def test_non_monotone_depths_are_refused(tmp_path, depths):
    path = _manifest(tmp_path, [np.ones((2, 2))] * 3, depths=depths)
    with pytest.raises(ModelParameterError, match=r"map\.json: field 'depths' is not strictly increasing"):
        load_stiffness_map(path)


def test_wrong_number_of_files_and_unknown_units(tmp_path):
    path = _manifest(tmp_path, [np.ones((2, 2))] * 2, depths=(2, 4, 6))
    with pytest.raises(ModelParameterError, match="names 2 files for 3 depths"):
        load_stiffness_map(path)
    path = _manifest(tmp_path, [np.ones((2, 2))] * 3, units={"force": "kgf"})
    with pytest.raises(ModelParameterError, match="field 'units.force' is 'kgf'; allowed: N, mN"):
        load_stiffness_map(path)


def test_npz_horizontal_shape_mismatch_and_missing_fields(tmp_path):
    np.savez(tmp_path / "a.npz", normal=np.ones((2, 3, 3)), horizontal=np.ones((2, 3, 4)), depths=[2, 3], dx=1, dy=1)
    with pytest.raises(
        ModelParameterError, match=r"a\.npz: field 'horizontal' has shape \(2, 3, 4\) but 'normal' has \(2, 3, 3\)"
    ):
        load_stiffness_map(tmp_path / "a.npz")
    np.savez(tmp_path / "b.npz", normal=np.ones((2, 3, 3)), depths=[2, 3], dx=1)
    with pytest.raises(ModelParameterError, match=r"b\.npz: field 'dy' is missing"):
        load_stiffness_map(tmp_path / "b.npz")


def test_missing_files(tmp_path):
    with pytest.raises(NotFoundError):
        load_stiffness_map(tmp_path / "nope.npz")
    doc = {"studyctl_stiffness_map": 1, "grid": {"dx": 1, "dy": 1}, "depths": [2], "normal": ["gone.csv"]}
    (tmp_path / "m.json").write_text(json.dumps(doc))
    with pytest.raises(NotFoundError, match="gone.csv: no such file"):
        load_stiffness_map(tmp_path / "m.json")


def test_arrays_validation():
    with pytest.raises(ModelParameterError, match="lists 2 depths but there are 3 force matrices"):
        StiffnessMap.from_arrays(np.ones((3, 2, 2)), [1, 2], dx_mm=1, dy_mm=1)
    with pytest.raises(ModelParameterError, match="grid.dx"):
        StiffnessMap.from_arrays(np.ones((1, 2, 2)), [1], dx_mm=0, dy_mm=1)
    with pytest.raises(ModelParameterError, match="positive"):
        StiffnessMap.from_arrays(np.ones((1, 2, 2)), [0.0], dx_mm=1, dy_mm=1)


def test_subsample_keeps_the_mapped_area_and_nodes():
    m = StiffnessMap.from_arrays(np.arange(2 * 9 * 5, dtype=float).reshape(2, 9, 5), [2, 4], dx_mm=1, dy_mm=1)
    s = m.subsample(2)
    assert s.extent_mm == m.extent_mm and s.shape == (2, 5, 3)
    np.testing.assert_array_equal(s.normal_n, m.normal_n[:, ::2, ::2])
    t = m.subsample(3)  # 3 does not divide 8: same extent, interpolated nodes
    assert t.extent_mm == pytest.approx(m.extent_mm) and t.shape == (2, 4, 3)


def test_to_frame_columns():
    frame = _map().to_frame()
    assert list(frame.columns) == ["depth_mm", "ix", "iy", "x_mm", "y_mm", "normal_n", "horizontal_n"]
    assert len(frame) == 3 * 5 * 4

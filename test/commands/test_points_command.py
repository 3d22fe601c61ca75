"""`changing-slam points MAP OUT.ply` (commands/points.py, io/ply.py): the file parses as PLY with one vertex per
map point that is not culled (active only unless --inactive), at the points' positions, which lie on the
simulated wall; bad input is one line and exit 1."""

from __future__ import annotations

import numpy as np
import pytest
from wall_scene import WALL_Z_M, map_wall

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.io.map_file import load_map, save_map

PLY_DTYPES = {"float": "<f4", "double": "<f8", "int": "<i4", "uint": "<u4", "short": "<i2", "ushort": "<u2",
              "uchar": "u1", "char": "i1"}  # fmt: skip


def read_ply(path) -> tuple[list[str], np.ndarray]:  # noqa: ANN001
    """A binary little-endian PLY with one `vertex` element, parsed from its header: (comments, rows)."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    assert lines[0] == "ply" and lines[1] == "format binary_little_endian 1.0" and lines[-1] == "end_header"
    count = next(int(ln.split()[2]) for ln in lines if ln.startswith("element vertex "))
    fields = [(ln.split()[2], PLY_DTYPES[ln.split()[1]]) for ln in lines if ln.startswith("property ")]
    rows = np.frombuffer(data[end:], dtype=np.dtype(fields))
    assert len(rows) == count  # no bytes missing or left over
    return [ln for ln in lines if ln.startswith("comment ")], rows


@pytest.fixture(scope="module")
def wall_map(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    return map_wall(tmp_path_factory.mktemp("wall") / "map.npz")


def test_points_writes_every_active_map_point_on_the_wall(wall_map, tmp_path, capsys) -> None:
    out = tmp_path / "points.ply"
    assert cli_main(["points", str(wall_map), str(out)]) == 0
    points = load_map(wall_map).atlas.current.points
    usable = np.flatnonzero(points.usable())
    assert len(usable) > 500
    comments, rows = read_ply(out)
    assert len(rows) == len(usable)
    assert f"wrote {out}: {len(usable)} points of map 0" in capsys.readouterr().out
    assert [n for n in rows.dtype.names] == ["x", "y", "z", "active", "observations", "class_id", "object_id"]
    xyz = np.column_stack([rows["x"], rows["y"], rows["z"]])
    assert np.allclose(xyz, points.positions[usable], atol=1e-6)
    assert np.median(np.abs(xyz[:, 2] - WALL_Z_M)) < 0.01  # the scene is one wall at z = 1.6 m
    assert (rows["active"] == 1).all() and (rows["observations"] >= 1).all() and (rows["object_id"] == -1).all()
    assert any("map 0" in c for c in comments)


def test_inactive_points_only_with_the_option(wall_map, tmp_path) -> None:
    loaded = load_map(wall_map)
    points = loaded.atlas.current.points
    usable = np.flatnonzero(points.usable())
    points.active[usable[:40]] = False  # as the object layer deactivates the points of an object that left
    changed = tmp_path / "map.npz"
    save_map(changed, loaded.atlas, None, loaded.next_keyframe_id)
    assert cli_main(["points", str(changed), str(tmp_path / "a.ply")]) == 0
    assert cli_main(["points", str(changed), str(tmp_path / "b.ply"), "--inactive"]) == 0
    _, active = read_ply(tmp_path / "a.ply")
    _, both = read_ply(tmp_path / "b.ply")
    assert (len(active), len(both)) == (len(usable) - 40, len(usable))
    assert int((both["active"] == 0).sum()) == 40


@pytest.mark.parametrize("argv, message", [
    (["{missing}", "{out}"], "missing.npz"),
    (["{map}", "{dir}/points.txt"], "output must be a .ply file"),
    (["{map}", "{out}", "--map-id", "7"], "no map 7 in the file (maps: 0)"),
])  # fmt: skip
def test_bad_input_is_one_line_and_exit_1(wall_map, tmp_path, capsys, argv, message) -> None:
    names = {"missing": str(tmp_path / "missing.npz"), "out": str(tmp_path / "p.ply"), "map": str(wall_map),
             "dir": str(tmp_path)}  # fmt: skip
    assert cli_main(["points", *[a.format(**names) for a in argv]]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("changing-slam points: error: ") and message in err and "\n" not in err
    assert not (tmp_path / "p.ply").exists()

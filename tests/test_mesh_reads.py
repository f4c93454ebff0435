"""One object, many jobs (issue 39, defect 10): a mesh file is read once per content for
every job's fingerprint (its side files) and pose (its triangles), and read again when it
changes. (benchmarks/bench_obj_planning.py has the scale figures.)"""

from __future__ import annotations

import os

import numpy as np


def _obj(path, shift=0.0, mtl="a.mtl"):
    path.write_text(f"mtllib {mtl}\nv {shift} 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n")


def test_a_mesh_is_parsed_once_per_content_for_its_jobs(tmp_path, monkeypatch):
    import trimesh

    from zcomp_cli import posed_mesh
    from zcomp_cli.blender import meshes

    (tmp_path / "a.mtl").write_text("newmtl m\nKd 1 1 1\n")
    (tmp_path / "b.mtl").write_text("newmtl m\nKd 1 0 0\n")
    obj = tmp_path / "o.obj"
    _obj(obj)
    loads = []
    real = trimesh.load
    monkeypatch.setattr(trimesh, "load", lambda *a, **k: loads.append(a[0]) or real(*a, **k))
    meta = {"mesh": str(obj), "object_to_camera": np.eye(4).tolist()}
    a = posed_mesh.load_posed_mesh(meta)
    b = posed_mesh.load_posed_mesh({**meta, "object_to_camera": (np.eye(4) * 2).tolist()})
    assert len(loads) == 1
    assert np.allclose(b.vertices, 2 * a.vertices)
    assert [p.name for p in meshes.side_files(obj)] == ["a.mtl"]
    opened = []
    real_open = open
    monkeypatch.setattr("builtins.open", lambda f, *a, **k: opened.append(str(f)) or real_open(f, *a, **k))
    for _ in range(5):
        assert [p.name for p in meshes.side_files(obj)] == ["a.mtl"]
    assert str(obj) not in opened  # the OBJ itself not read again
    monkeypatch.setattr("builtins.open", real_open)
    # a changed file is read again (its size or time changes its key)
    _obj(obj, shift=0.5, mtl="b.mtl")
    st = obj.stat()
    os.utime(obj, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000))
    c = posed_mesh.load_posed_mesh(meta)
    assert len(loads) == 2 and c.vertices[0, 0] == 0.5
    assert [p.name for p in meshes.side_files(obj)] == ["b.mtl"]

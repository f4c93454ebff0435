"""Shadow rays against a triangle mesh (renderers/physical/raycast.py): occlusion and
first-hit distance against a unit cube with known answers, robustness to bad rays, and
the Embree and trimesh backends agreeing."""

import sys

import numpy as np
import pytest

from zcomp_cli.scene.raycast import RayCaster, embree_available


def _has_rtree() -> bool:
    try:
        import rtree  # noqa: F401
    except ImportError:
        return False
    return True


# Bug (reported): the fallback, trimesh's own ray-triangle intersector, builds an r-tree
# with ``rtree``, which neither zcomp nor trimesh's base install depends on: where
# ``embreex`` is absent (the very machines the fallback is for), the first ray raises
# ModuleNotFoundError. Passes once rtree is a dependency or the fallback does without it.
FALLBACK_NEEDS_RTREE = pytest.mark.xfail(
    not _has_rtree(), raises=ModuleNotFoundError, strict=True,
    reason="raycast's trimesh fallback needs `rtree`, which is not a dependency (ModuleNotFoundError: rtree)")

# a unit cube [-0.5, 0.5]^3: 8 corners (index 4 x + 2 y + z), 12 triangles
CUBE_V = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], np.float64)
_QUADS = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
CUBE_F = np.array([t for a, b, c, d in _QUADS for t in ((a, b, c), (a, c, d))], np.int64)


def _trimesh_caster(vertices, faces, monkeypatch) -> RayCaster:
    """A RayCaster on trimesh's own intersector, as on a machine without ``embreex``: the
    import of embreex fails, and trimesh does not route its rays through Embree either."""
    import trimesh.ray

    with monkeypatch.context() as m:
        m.setitem(sys.modules, "embreex", None)
        m.setattr(trimesh.ray, "has_embree", False)
        rc = RayCaster(vertices, faces)
    assert rc.backend == "trimesh"
    return rc


@pytest.fixture(params=["embree", pytest.param("trimesh", marks=FALLBACK_NEEDS_RTREE)])
def make(request, monkeypatch):
    """``make(vertices, faces)``: a RayCaster on the parametrised backend."""
    if request.param == "embree" and not embree_available():
        pytest.skip("embreex is not installed")

    def build(vertices, faces):
        if request.param == "trimesh":
            return _trimesh_caster(vertices, faces, monkeypatch)
        rc = RayCaster(vertices, faces)
        assert rc.backend == "embree"
        return rc

    return build


@pytest.fixture
def cube(make):
    return make(CUBE_V, CUBE_F)


def test_shapes_and_counts(cube):
    assert cube.n_faces == 12
    o = np.zeros((5, 3)) + [0.1, 0.2, -5.0]
    assert cube.occluded(o, [0, 0, 1.0]).shape == (5,) and cube.occluded(o, [0, 0, 1.0]).dtype == bool
    assert cube.hit_distance(o, np.tile([0, 0, 1.0], (5, 1))).shape == (5,)
    assert cube.occluded(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
    assert cube.hit_distance(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


def test_through_beside_and_away(cube):
    o = np.array([[0.1, 0.2, -5.0],   # toward the cube along +z: through it
                  [0.1, 0.2, -5.0],   # away from it
                  [0.9, 0.2, -5.0],   # beside it (x beyond 0.5)
                  [-4.0, -0.3, 0.25],  # along +x through it
                  [-4.0, 0.7, 0.25],  # along +x above it
                  [3.0, 3.0, 3.0]])   # along the diagonal toward the centre
    d = np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, 1.0], [1.0, 0, 0], [1.0, 0, 0], -np.ones(3) / np.sqrt(3)])
    assert cube.occluded(o, d).tolist() == [True, False, False, True, False, True]
    assert np.isinf(cube.hit_distance(o, d)[[1, 2, 4]]).all()


def test_tmax_shorter_than_the_hit_is_not_occluded(cube):
    o = np.array([[0.1, 0.2, -5.0]] * 3)
    d = [0, 0, 1.0]  # the cube's face is 4.5 away
    assert cube.occluded(o, d, tmax=np.array([4.4, 4.6, 100.0])).tolist() == [False, True, True]
    assert not cube.occluded(o[:1], d, tmax=4.0)[0] and cube.occluded(o[:1], d, tmax=5.0)[0]
    # a non-positive tmax: nothing lies closer
    assert not cube.occluded(o[:1], d, tmax=0.0)[0] and not cube.occluded(o[:1], d, tmax=-1.0)[0]


def test_hit_distance_is_exact_for_axis_rays(cube):
    o = np.array([[0.1, 0.2, -5.0], [0.1, 0.2, 5.0], [-3.0, 0.1, -0.2], [0.2, 7.25, 0.3], [0.1, -0.2, 0.3]])
    d = np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, -1.0, 0], [0, 1.0, 0]])
    # the last ray starts inside the cube: it meets the top face from within
    want = np.array([4.5, 4.5, 2.5, 6.75, 0.7])
    np.testing.assert_allclose(cube.hit_distance(o, d), want, atol=1e-4)


def test_bad_rays_are_never_occluded_and_do_not_raise(cube):
    o = np.array([[np.nan, 0.2, -5.0], [0.1, np.inf, -5.0], [0.1, 0.2, -5.0], [0.1, 0.2, -5.0], [0.1, 0.2, -5.0],
                  [0.1, 0.2, -5.0]])
    d = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 0.0], [np.nan, 0, 1.0], [0, -np.inf, 1.0], [0, 0, 1.0]])
    occ = cube.occluded(o, d)
    assert occ.tolist() == [False] * 5 + [True]  # the last, a good ray, still answers
    dist = cube.hit_distance(o, d)
    assert np.isinf(dist[:5]).all() and abs(dist[5] - 4.5) < 1e-4
    assert not cube.occluded(o[2:3], d[2:3], tmax=np.nan)[0]


def test_an_empty_mesh_occludes_nothing():
    for rc in (RayCaster(np.zeros((0, 3)), np.zeros((0, 3), np.int64)),
               RayCaster(CUBE_V, np.zeros((0, 3), np.int64))):
        assert rc.backend == "none" and rc.n_faces == 0
        o = np.random.default_rng(0).normal(size=(50, 3))
        d = np.random.default_rng(1).normal(size=(50, 3))
        assert not rc.occluded(o, d).any()
        assert np.isinf(rc.hit_distance(o, d)).all()


def test_faces_with_a_non_finite_corner_are_dropped():
    v = CUBE_V.copy()
    v[0] = np.nan  # corner 0 is in 6 of the 12 triangles
    rc = RayCaster(v, CUBE_F)
    assert rc.n_faces == int((~np.any(CUBE_F == 0, axis=1)).sum()) == 6
    v[:] = np.inf
    assert RayCaster(v, CUBE_F).backend == "none"


@pytest.mark.parametrize("faces", [[[0, 1, 8]], [[0, -1, 2]], [[0, 1, 100]]])
def test_out_of_range_face_indices_raise(faces):
    with pytest.raises(ValueError, match="out of range"):
        RayCaster(CUBE_V, np.asarray(faces))


def test_unused_vertices_do_not_change_the_answers(make):
    # far-away stray vertices referenced by no face
    v = np.concatenate([CUBE_V, [[1e6, 1e6, 1e6], [np.nan, 0, 0]]])
    rc = make(v, CUBE_F)
    o = np.array([[0.1, 0.2, -5.0], [0.9, 0.2, -5.0]])
    assert rc.occluded(o, [0, 0, 1.0]).tolist() == [True, False]
    np.testing.assert_allclose(rc.hit_distance(o[:1], [0, 0, 1.0]), [4.5], atol=1e-4)


def test_direction_length_does_not_change_occlusion(cube):
    o = np.array([[0.1, 0.2, -5.0], [0.9, 0.2, -5.0]])
    for scale in (0.5, 1.0, 2.0):
        assert cube.occluded(o, [0, 0, scale]).tolist() == [True, False]


@pytest.mark.skipif(not embree_available(), reason="embreex is not installed")
def test_hit_distance_is_metres_whatever_the_direction_length():
    rc = RayCaster(CUBE_V, CUBE_F)
    o = np.array([[0.1, 0.2, -5.0]] * 3)
    d = np.array([[0, 0, 0.5], [0, 0, 1.0], [0, 0, 2.0]])
    np.testing.assert_allclose(rc.hit_distance(o, d), [4.5, 4.5, 4.5], atol=1e-4)


@pytest.mark.skipif(not embree_available(), reason="embreex is not installed")
@FALLBACK_NEEDS_RTREE
def test_embree_and_trimesh_agree_on_random_rays(monkeypatch):
    import trimesh

    sph = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    rng = np.random.default_rng(7)
    n = 2000
    o = rng.uniform(-2.0, 2.0, size=(n, 3))
    o[: n // 2] *= 1.5  # half from further out
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # aim a third of the rays at the sphere so both answers are well represented
    aim = rng.normal(scale=0.5, size=(n // 3, 3)) - o[: n // 3]
    d[: n // 3] = aim / np.linalg.norm(aim, axis=1, keepdims=True)
    tmax = rng.uniform(0.2, 5.0, size=n)
    em = RayCaster(sph.vertices, sph.faces)
    tm = _trimesh_caster(sph.vertices, sph.faces, monkeypatch)
    assert em.backend == "embree" and tm.backend == "trimesh"
    de, dt = em.hit_distance(o, d), tm.hit_distance(o, d)
    hit_e, hit_t = np.isfinite(de), np.isfinite(dt)
    assert 0.3 < hit_e.mean() < 0.9  # both outcomes are exercised
    # grazing rays along an edge may go either way in float32: at most a few
    assert (hit_e != hit_t).sum() <= 2
    both = hit_e & hit_t
    np.testing.assert_allclose(de[both], dt[both], atol=1e-4)
    oe, ot = em.occluded(o, d, tmax), tm.occluded(o, d, tmax)
    assert 0.1 < oe.mean() < 0.9
    assert (oe != ot).sum() <= 2
    # occlusion within tmax is the first hit closer than tmax
    assert (oe == (de < tmax)).mean() > 0.998


def test_chunking_does_not_change_the_answers(cube, monkeypatch):
    from zcomp_cli.scene import raycast

    rng = np.random.default_rng(3)
    o = rng.uniform(-2, 2, size=(300, 3))
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = rng.uniform(0.1, 3.0, size=300)
    occ, dist = cube.occluded(o, d, t), cube.hit_distance(o, d)
    assert 0 < occ.sum() < 300
    monkeypatch.setattr(raycast, "RAY_CHUNK", 7)
    assert (cube.occluded(o, d, t) == occ).all()
    np.testing.assert_array_equal(cube.hit_distance(o, d), dist)


def _grid_rays(n=40, k=9, seed=5):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-2, 2, size=(n, 3))
    d = rng.normal(size=(k, 3)) * rng.uniform(0.5, 3.0, size=(k, 1))  # not unit: normalised inside
    o[3] = np.nan  # a bad origin and a bad direction: never occluded, never raise
    d[2] = 0.0
    return o, d


def test_occluded_grid_is_occluded_on_every_pair(cube):
    o, d = _grid_rays()
    got = cube.occluded_grid(o, d)
    assert got.shape == (len(d), len(o))
    want = np.stack([cube.occluded(o, dk) for dk in d])
    np.testing.assert_array_equal(got, want)
    assert 0 < got.sum() < got.size
    assert not got[:, 3].any() and not got[2].any()


def test_occluded_grid_traces_only_the_live_pairs(cube):
    o, d = _grid_rays()
    full = cube.occluded_grid(o, d)
    live = np.random.default_rng(1).random(full.shape) < 0.5
    got = cube.occluded_grid(o, d, live)
    np.testing.assert_array_equal(got, full & live)
    assert not cube.occluded_grid(o, d, np.zeros_like(live)).any()


def test_threads_change_no_answer(cube, monkeypatch):
    """The queries split over threads (and over parts of directions) give each ray the
    answer it has in one piece; a query made from inside the pool runs on its own thread."""
    from zcomp_cli import threads
    from zcomp_cli.scene import raycast

    rng = np.random.default_rng(7)
    o = rng.uniform(-2, 2, size=(2000, 3))
    d = rng.normal(size=(2000, 3))
    t = rng.uniform(0.1, 3.0, size=2000)
    og, dg = _grid_rays(n=300, k=11)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    one = cube.occluded(o, d, t), cube.hit_distance(o, d), cube.occluded_grid(og, dg)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    monkeypatch.setattr(raycast, "MIN_THREAD_RAYS", 64)
    many = cube.occluded(o, d, t), cube.hit_distance(o, d), cube.occluded_grid(og, dg)
    for a, b in zip(one, many):
        np.testing.assert_array_equal(a, b)
    inside = threads.pool().submit(lambda: (cube.occluded(o, d, t), cube.occluded_grid(og, dg))).result()
    np.testing.assert_array_equal(inside[0], one[0])
    np.testing.assert_array_equal(inside[1], one[2])


def test_direction_count_must_match_the_origins(cube):
    with pytest.raises(ValueError, match="3 origins but 2 directions"):
        cube.occluded(np.zeros((3, 3)), np.ones((2, 3)))

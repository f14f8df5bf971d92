"""Named boundaries: tags read from mesh files (gmsh physical groups, meshio cell sets),
written back by ``pdeinv.fem.mesh.save``, kept by refinement, and used for Dirichlet selection."""

from pathlib import Path

import meshio
import numpy as np
import pytest

import pdeinv
from pdeinv import mesh
from pdeinv.cli import main
from pdeinv.fem.forms import discretize
from pdeinv.fem.mesh import _facet_tags

PLATE = Path(__file__).resolve().parents[1] / "problems" / "meshes" / "plate.msh"


def _square():
    return mesh.unit_square(4).with_boundaries({
        "left": lambda x: np.isclose(x[0], 0.0),
        "top": lambda x: np.isclose(x[1], 1.0),
    })


def _edges(m, name):
    """The named boundary as a set of sorted node pairs."""
    return {tuple(e) for e in np.sort(m.facets[:, m.boundaries[name]], axis=0).T}


def test_tags_survive_save_and_load(tmp_path):
    m = _square()
    mesh.save(tmp_path / "sq.msh", m)
    back = mesh.load(tmp_path / "sq.msh")
    assert sorted(back.boundaries) == ["left", "top"]
    for name in ("left", "top"):
        assert len(back.boundaries[name]) == 4 and _edges(back, name) == _edges(m, name)
    assert np.allclose(back.p[0, back.facets[:, back.boundaries["left"]]], 0.0)
    assert np.allclose(back.p[1, back.facets[:, back.boundaries["top"]]], 1.0)


def test_refinement_keeps_tags(tmp_path):
    mesh.save(tmp_path / "sq.msh", _square())
    fine = mesh.load(tmp_path / "sq.msh").refined(2)
    assert len(fine.boundaries["left"]) == 16
    assert np.allclose(fine.p[0, fine.facets[:, fine.boundaries["left"]]], 0.0)


def test_unused_nodes_are_dropped_and_tags_remapped(tmp_path):
    m = _square()
    extra = np.vstack([np.array([[5.0, 5.0]]), m.p.T])  # node 0 unused, every index shifts by one
    lines = m.facets[:, m.boundaries["left"]].T + 1
    meshio.write(tmp_path / "shift.msh", meshio.Mesh(
        extra, [("triangle", m.t.T + 1), ("line", lines)],
        cell_data={"gmsh:physical": [np.full(m.t.shape[1], 2), np.full(4, 1)],
                   "gmsh:geometrical": [np.full(m.t.shape[1], 2), np.full(4, 1)]},
        field_data={"wall": np.array([1, 1]), "domain": np.array([2, 2])}), file_format="gmsh22")
    back = mesh.load(tmp_path / "shift.msh")
    assert back.p.shape[1] == m.p.shape[1]
    assert np.allclose(back.p[0, back.facets[:, back.boundaries["wall"]]], 0.0)


#: what gmsh itself writes (format 4.1): the unit square, two triangles, the edge x = 0 named "left"
GMSH41 = """$MeshFormat
4.1 0 8
$EndMeshFormat
$PhysicalNames
2
1 1 "left"
2 2 "domain"
$EndPhysicalNames
$Entities
0 1 1 0
1 0 0 0 0 1 0 1 1 0
1 0 0 0 1 1 0 1 2 0
$EndEntities
$Nodes
2 4 1 4
1 1 0 2
1
4
0 0 0
0 1 0
2 1 0 2
2
3
1 0 0
1 1 0
$EndNodes
$Elements
2 3 1 3
1 1 1 1
1 1 4
2 1 2 2
2 1 2 3
3 1 3 4
$EndElements
"""


def test_gmsh41_physical_names(tmp_path):
    (tmp_path / "sq.msh").write_text(GMSH41)
    m = mesh.load(tmp_path / "sq.msh")
    assert sorted(m.boundaries) == ["left"]
    ends = m.p[:, m.facets[:, m.boundaries["left"]]][..., 0]  # (x, y) of the edge's two nodes
    np.testing.assert_array_equal(np.sort(ends), [[0, 0], [0, 1]])
    assert discretize(m, dirichlet="left").N == 2


def test_cell_sets_and_unnamed_physical_groups():
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    m = meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]])), ("line", np.array([[0, 1], [1, 2], [2, 0]]))],
                    cell_sets={"bottom": [np.array([], dtype=int), np.array([0])]})
    assert {k: v.tolist() for k, v in _facet_tags(m, "line").items()} == {"bottom": [[0, 1]]}
    m = meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]])), ("line", np.array([[0, 1], [2, 0]]))],
                    cell_data={"gmsh:physical": [np.array([9]), np.array([7, 8])]})
    assert sorted(_facet_tags(m, "line")) == ["7", "8"]  # no field_data: named by their numbers


def test_tag_that_is_not_an_edge_is_refused(tmp_path):
    m = mesh.unit_square(2)
    path = tmp_path / "bad.msh"
    meshio.write(path, meshio.Mesh(
        m.p.T, [("triangle", m.t.T), ("line", np.array([[0, 8]]))],  # opposite corners: no edge
        cell_data={"gmsh:physical": [np.full(m.t.shape[1], 2), np.array([1])],
                   "gmsh:geometrical": [np.full(m.t.shape[1], 2), np.array([1])]},
        field_data={"diagonal": np.array([1, 1])}), file_format="gmsh22")
    with pytest.raises(ValueError, match=r"bad.msh.*tag 'diagonal' has 1 of 1 line cells that are not edges"):
        mesh.load(path)


def test_dirichlet_by_name():
    m = _square()
    every = discretize(m, dirichlet=False).basis.N
    assert every - discretize(m, dirichlet="left").N == 5
    assert every - discretize(m, dirichlet=["left", "top"]).N == 9  # corner (0, 1) shared
    with pytest.raises(ValueError, match=r"boundary 'right' is not a named boundary.*\['left', 'top'\]"):
        discretize(m, dirichlet="right")
    with pytest.raises(ValueError, match=r"'left'.*no named boundaries"):
        discretize(mesh.unit_square(4), dirichlet="left")


# -- the plate problem uses its file's tags ------------------------------------------------------------

def _fixed(p):
    return np.setdiff1d(np.arange(p.disc.basis.N), p.disc.free)


def test_plate_file_names_outer_and_hole():
    m = mesh.load(PLATE)
    assert {k: len(v) for k, v in m.boundaries.items()} == {"outer": 64, "hole": 64}
    hole = m.p[:, m.facets[:, m.boundaries["hole"]]]
    assert np.allclose(np.linalg.norm(hole - np.array([[[0.42]], [[0.56]]]), axis=0), 0.2)


def test_plate_dirichlet_setting(tmp_path):
    outer = pdeinv.load_problem("heat_plate", refine=0, backend="steps", steps=5)
    both = pdeinv.load_problem("heat_plate", refine=0, backend="steps", steps=5, dirichlet="outer, hole")
    assert len(_fixed(both)) == len(_fixed(outer)) + 64
    assert both.settings["dirichlet"] == "outer,hole"
    # the same plate without tags (VTU keeps none): the geometric outer loop gives the same DOFs
    untagged = tmp_path / "plate.vtu"
    mesh.save(untagged, mesh.load(PLATE))
    assert not mesh.load(untagged).boundaries
    geo = pdeinv.load_problem("heat_plate", refine=0, backend="steps", steps=5, mesh=str(untagged))
    np.testing.assert_array_equal(_fixed(geo), _fixed(outer))
    with pytest.raises(ValueError, match=r"boundary 'hole' is not a named boundary.*no named boundaries"):
        pdeinv.load_problem("heat_plate", refine=0, mesh=str(untagged), dirichlet="hole")
    with pytest.raises(ValueError, match=r"boundary 'rim' is not a named boundary.*\['hole', 'outer'\]"):
        pdeinv.load_problem("heat_plate", refine=0, dirichlet="rim")
    with pytest.raises(ValueError, match=r"dirichlet=',' is not allowed; expected names"):
        pdeinv.load_problem("heat_plate", refine=0, dirichlet=",")


def test_cli_unknown_boundary_name(tmp_path, capsys):
    code = main(["train", "--prior-fit", "0", "heat_plate", "--set", "refine=0", "--set", "dirichlet=rim",
                 "--out", str(tmp_path / "run"), "--steps", "1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "'rim'" in err and "Traceback" not in err

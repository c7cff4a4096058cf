"""Dataset layouts: TOSCA-style pairs, PSB segmentations, plain folders, synthetic poses."""

from __future__ import annotations

import numpy as np
import pytest

from shape_toolkit.data.datasets import (
    folder_dataset,
    load_item,
    open_dataset,
    psb_dataset,
    synthetic_refs,
    tosca_dataset,
)
from shape_toolkit.data.generate import icosphere
from shape_toolkit.data.synthetic import synthetic_dataset
from shape_toolkit.errors import ParameterError, ShapeFileError
from shape_toolkit.io.mesh import save_shape


def test_synthetic_poses_share_connectivity_and_labels():
    poses = synthetic_dataset(3, subdivisions=2, random_state=4)
    assert np.array_equal(poses[0].angles, np.zeros(5))
    assert all(np.array_equal(p.shape.faces, poses[0].shape.faces) for p in poses)
    assert all(np.array_equal(p.labels, poses[0].labels) for p in poses)
    assert not np.allclose(poses[1].shape.vertices, poses[2].shape.vertices)
    refs = synthetic_refs(3, subdivisions=2, random_state=4)
    item = load_item(refs[1])
    assert np.array_equal(item.shape.vertices, poses[1].shape.vertices)
    assert np.array_equal(item.target.vertices, poses[2].shape.vertices)
    assert np.array_equal(item.correspondence[:, 0], item.correspondence[:, 1])
    assert np.array_equal(item.labels[0], poses[1].labels)


def test_synthetic_limb_lengths_make_the_limbs_differ():
    """``limb_lengths``: each limb's tip moves out or in by about its length's change from the alike limbs'
    1.4 (measured within 0.06), the same vertex count and labels as with alike limbs; a wrong count is
    refused when the dataset is opened, before any shape is built."""
    lengths = [1.4, 1.2, 1.55, 1.35, 0.8]
    alike = synthetic_dataset(1, subdivisions=2)[0]
    apart = synthetic_dataset(1, subdivisions=2, limb_lengths=lengths)[0]
    assert apart.shape.n_vertices == alike.shape.n_vertices and np.array_equal(apart.labels, alike.labels)
    def reach(a):
        return np.array([np.linalg.norm(a.shape.vertices[a.labels == j + 1], axis=1).max() for j in range(5)])

    np.testing.assert_allclose(reach(apart) - reach(alike), np.array(lengths) - 1.4, atol=0.06)
    item = load_item(synthetic_refs(2, subdivisions=2, limb_lengths=lengths)[0])
    assert np.array_equal(item.shape.vertices, apart.shape.vertices)
    with pytest.raises(ParameterError, match="5 positive lengths"):
        synthetic_refs(2, limb_lengths=[1.0, 2.0])
    with pytest.raises(ParameterError, match="5 lengths"):
        synthetic_dataset(1, limb_lengths=[1.0])


def _write_tosca(root, names=("cat0", "cat1")):
    (root / "corres").mkdir(parents=True)
    s = icosphere(1)
    for k, n in enumerate(names):
        perm = np.roll(np.arange(s.n_vertices), k)  # vertex i of cat_k is vertex perm[i] of the sphere
        inv = np.argsort(perm)
        from shape_toolkit.core.shape import Shape

        save_shape(Shape(s.vertices[perm], inv[s.faces]), root / f"{n}.off")
        # row j: the point that is sphere vertex j, 1-based
        (root / "corres" / f"{n}.vts").write_text("\n".join(str(inv[j] + 1) for j in range(s.n_vertices)))
    (root / "pairs.txt").write_text(f"{names[0]}\t{names[1]}\n")
    return s


def test_tosca_layout(tmp_path):
    s = _write_tosca(tmp_path)
    refs = tosca_dataset(tmp_path)
    assert [r.name for r in refs] == ["cat0-cat1"]
    item = load_item(refs[0])
    a, b = item.correspondence[:, 0], item.correspondence[:, 1]
    np.testing.assert_array_equal(item.shape.vertices[a], item.target.vertices[b])
    assert item.shape.n_vertices == s.n_vertices
    (tmp_path / "pairs.txt").write_text("cat0\tdog9\n")
    with pytest.raises(ShapeFileError, match="missing"):
        tosca_dataset(tmp_path)


def test_psb_layout_and_folder(tmp_path):
    s = icosphere(1)
    (tmp_path / "off").mkdir()
    (tmp_path / "seg" / "7").mkdir(parents=True)
    save_shape(s, tmp_path / "off" / "7.off")
    for k in range(2):
        lab = (s.vertices[s.faces].mean(axis=1)[:, k] > 0).astype(int)
        (tmp_path / "seg" / "7" / f"7_{k}.seg").write_text("\n".join(map(str, lab)))
    refs = psb_dataset(tmp_path)
    item = load_item(refs[0])
    assert len(item.face_labels) == 2 and len(item.labels) == 2
    assert item.labels[0].shape == (s.n_vertices,)
    # vertices well inside a half take that half's label
    inside = s.vertices[:, 0] > 0.5
    assert np.all(item.labels[0][inside] == 1)
    with pytest.raises(ParameterError):
        open_dataset("nope", tmp_path)
    folder = tmp_path / "plain"
    folder.mkdir()
    save_shape(s, folder / "ball.ply")
    (folder / "ball.labels").write_text("\n".join("1" for _ in range(s.n_vertices)))
    (folder / "notes.txt").write_text("x")
    refs = folder_dataset(folder)
    assert [r.name for r in refs] == ["ball"]
    assert load_item(refs[0]).labels[0].sum() == s.n_vertices


def test_shared_tosca_and_psb(shared_data):
    refs = tosca_dataset(shared_data / "tosca5k")
    assert len(refs) == 24
    item = load_item(refs[0])
    assert item.correspondence.shape == (5000, 2) and item.symmetric_correspondence is not None
    p = psb_dataset(shared_data / "psb")
    assert [r.name for r in p][:2] == ["1", "2"]
    it = load_item(p[0])
    assert len(it.face_labels) >= 2 and all(len(f) == it.shape.n_faces for f in it.face_labels)


def test_tosca_classes_keep_whole_animals(shared_data):
    """classes = a split by animal: only pairs whose both shapes are of a listed class; an unknown class
    is refused, naming it."""
    refs = tosca_dataset(shared_data / "tosca5k", classes=["dog", "wolf"])
    assert [r.name for r in refs] == [f"{a}-{b}" for a, b in (
        ("dog0", "dog1"), ("dog0", "dog2"), ("dog0", "dog3"), ("dog1", "dog2"), ("dog1", "dog3"), ("dog2", "dog3"),
        ("wolf0", "wolf1"), ("wolf0", "wolf2"), ("wolf1", "wolf2"))]
    with pytest.raises(ParameterError, match="unknown class 'horse'"):
        tosca_dataset(shared_data / "tosca5k", classes=["horse"])

"""The template's embedding carries the lower inner lip with the jaw (`correspondence.carried_by_jaw`)."""
import numpy as np
import pytest

from avatarkit.face.correspondence import (LOWER_INNER_LIP, JAW_CARRIED, carried_by_jaw, embedding_for,
                                           template_embedding)
from avatarkit.face.fit import JAW_JOINT, LandmarkModel
from avatarkit.head.model import HeadModel


@pytest.fixture(scope="module")
def model():
    return HeadModel.template()


def _jaw_weight(model, emb):
    w = np.asarray(model.weights[:, JAW_JOINT], np.float64)
    return np.einsum("kj,kj->k", emb.bary, w[np.asarray(model.faces)[emb.face_idx]])


def test_the_lower_inner_lip_opens_with_the_jaw_and_nothing_moves_at_rest(model):
    raw, emb = template_embedding(), embedding_for(model)
    assert emb is not None and np.array_equal(emb.mesh_index, raw.mesh_index)
    lower = np.isin(emb.mesh_index, LOWER_INNER_LIP)
    assert lower.sum() >= 3
    # the shipped file puts them where the jaw does not reach (the reason for the re-hosting)
    assert (_jaw_weight(model, raw)[lower] < JAW_CARRIED).all()
    assert (_jaw_weight(model, emb)[lower] >= JAW_CARRIED).all()
    # every landmark keeps its rest position, with and without an identity shape
    shape = np.random.default_rng(0).normal(0, 0.5, model.num_shape)
    np.testing.assert_allclose(LandmarkModel(model, emb).points_numpy(), LandmarkModel(model, raw).points_numpy(),
                               atol=1e-12)
    # the other rows are the file's own
    assert np.array_equal(emb.face_idx[~lower], raw.face_idx[~lower])
    assert np.abs(emb.offset[~lower]).max() == 0
    # jaw open by 0.2 rad: the lower inner lip drops like the outer lower lip's middle, the
    # upper inner lip stays; in the file's embedding the lower inner lip stays too
    jaw = np.array([0.2, 0.0, 0.0])
    for e, moves in ((emb, True), (raw, False)):
        lm = LandmarkModel(model, e)
        drop = lm.points_numpy(shape, None, jaw)[:, 1] - lm.points_numpy(shape)[:, 1]
        outer = drop[emb.mesh_index == 17][0]
        assert outer < -0.005
        assert np.abs(drop[np.isin(emb.mesh_index, (13, 82, 312))]).max() < 1e-4
        if moves:
            assert (drop[lower] < 0.5 * outer).all()
        else:
            assert np.abs(drop[lower]).max() < 1e-4


def test_re_hosting_is_idempotent(model):
    emb = embedding_for(model)
    again = carried_by_jaw(emb, model)
    assert np.array_equal(again.face_idx, emb.face_idx)
    np.testing.assert_array_equal(again.offset, emb.offset)


def test_the_portrait_fits_keep_the_files_hosting(model):
    """The build's fit and `avatarkit face` have no jaw: there the re-hosted points would follow
    the lower lip's expressions instead (the sample portrait's rotation moved 1.9 degrees and
    its front view lost 0.2 dB), so they take the file's hosting; the tracker the re-hosted."""
    from types import SimpleNamespace

    from avatarkit.recon.fit import _mesh_targets

    raw = template_embedding()
    assert np.array_equal(embedding_for(model, carry_jaw=False).face_idx, raw.face_idx)
    mesh = SimpleNamespace(points=np.zeros((468, 3)), iris_centers=np.zeros((2, 2)))
    mesh.points[:, :2] = np.random.default_rng(1).uniform(100, 400, (468, 2))
    _, lm = _mesh_targets(SimpleNamespace(mesh=mesh, image_size=(512, 512)), model)
    np.testing.assert_array_equal(lm.embedding.face_idx, raw.face_idx)
    assert lm.embedding.offset is None or np.abs(lm.embedding.offset).max() == 0

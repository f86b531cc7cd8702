"""Linear blend skinning in the FLAME/SMPL formulation, batched over frames.

    v_shaped  = v_template + shapedirs . shape + exprdirs . expr            (blendshapes)
    J         = J_regressor @ v_shaped                                       (rest joints)
    R_j       = Rodrigues(pose_j)                                            (axis-angle per joint)
    v_posed   = v_shaped + posedirs^T . vec(R_1.. - I)                       (pose correctives)
    G_j       = G_parent(j) [R_j | J_j - J_parent(j)]                        (kinematic chain)
    A_j       = G_j [I | -J_j]                                               (rest -> posed)
    v         = sum_j w_vj A_j v_posed + translation

Three implementations of the same maths: `lbs` (vectorised numpy, the one the library uses),
`lbs_reference` (slow and obvious: loops over frames and joints; tests compare against it) and
`lbs_torch` (differentiable w.r.t. every per-frame input; torch is imported lazily).
"""
from __future__ import annotations

import numpy as np

from avatarkit.rotations import axis_angle_to_matrix


def _regress(J_regressor, v: np.ndarray) -> np.ndarray:
    """J_regressor (J, V) dense or scipy.sparse; v (T, V, 3) -> joints (T, J, 3)."""
    T, V, _ = v.shape
    flat = np.ascontiguousarray(np.moveaxis(v, 0, 1)).reshape(V, T * 3)
    out = np.asarray(J_regressor @ flat)  # sparse @ dense gives a dense array
    return np.moveaxis(out.reshape(-1, T, 3), 1, 0)


def rigid_transforms(rot: np.ndarray, joints: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """rot (T, J, 3, 3), joints (T, J, 3) rest positions, parents (J,) with parents[0] = -1 and
    parents[j] < j -> skinning transforms A (T, J, 4, 4) mapping rest points to posed points."""
    T, J = rot.shape[:2]
    local = np.zeros((T, J, 4, 4), dtype=np.float64)
    local[:, :, :3, :3] = rot
    local[:, :, 3, 3] = 1.0
    rel = joints.astype(np.float64).copy()
    rel[:, 1:] -= joints[:, parents[1:]]
    local[:, :, :3, 3] = rel
    world = np.empty_like(local)
    world[:, 0] = local[:, 0]
    for j in range(1, J):  # J is 5 for FLAME: a loop over joints, not vertices
        world[:, j] = world[:, parents[j]] @ local[:, j]
    A = world.copy()
    A[:, :, :3, 3] -= np.einsum("tjab,tjb->tja", world[:, :, :3, :3], joints)
    return A


def lbs(v_shaped: np.ndarray, J_regressor, parents: np.ndarray, weights: np.ndarray,
        pose: np.ndarray, translation: np.ndarray, posedirs: np.ndarray | None = None,
        joints: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pose blend-shaped vertices.

    v_shaped: (T, V, 3) template + shape + expression offsets; J_regressor: (J, V) dense or sparse;
    parents: (J,); weights: (V, J); pose: (T, J, 3) axis-angle; translation: (T, 3);
    posedirs: (9 (J-1), V*3) or None; joints: (T, J, 3) rest joints (regressed when None).
    Returns vertices (T, V, 3) float32 and joint transforms A (T, J, 4, 4) float32 (global
    translation included: a point fully weighted to joint j moves by A[t, j]).
    """
    v_shaped = np.asarray(v_shaped, dtype=np.float32)
    T, V, _ = v_shaped.shape
    J = len(parents)
    if joints is None:
        joints = _regress(J_regressor, v_shaped.astype(np.float64))
    rot = axis_angle_to_matrix(np.asarray(pose, dtype=np.float64).reshape(T, J, 3))
    v_posed = v_shaped
    if posedirs is not None and len(posedirs):
        feat = (rot[:, 1:] - np.eye(3)).reshape(T, -1).astype(np.float32)  # (T, 9 (J-1))
        v_posed = v_shaped + (feat @ posedirs).reshape(T, V, 3)
    A = rigid_transforms(rot, joints, np.asarray(parents))
    A[:, :, :3, 3] += np.asarray(translation, dtype=np.float64)[:, None, :]
    A32 = A.astype(np.float32)
    # Blend the 3x4 part of each joint's transform per vertex with one BLAS product
    # (V, J) @ (T, J, 12) -> (T, V, 12), then apply it with elementwise products (einsum does
    # not reach BLAS for these shapes and is several times slower).
    M = np.matmul(np.asarray(weights, dtype=np.float32), A32[:, :, :3, :].reshape(T, J, 12)).reshape(T, V, 3, 4)
    verts = M[..., 3].copy()
    for k in range(3):
        verts += M[..., k] * v_posed[:, :, k, None]
    return verts, A32


def lbs_reference(v_shaped, J_regressor, parents, weights, pose, translation, posedirs=None):
    """The same maths written plainly (float64, loops over frames and joints). For tests only."""
    v_shaped = np.asarray(v_shaped, dtype=np.float64)
    T, V, _ = v_shaped.shape
    J = len(parents)
    Jreg = J_regressor.toarray() if hasattr(J_regressor, "toarray") else np.asarray(J_regressor, np.float64)
    W = np.asarray(weights, dtype=np.float64)
    out_v = np.zeros((T, V, 3))
    out_a = np.zeros((T, J, 4, 4))
    for t in range(T):
        joints = Jreg @ v_shaped[t]
        rots = [axis_angle_to_matrix(np.asarray(pose[t][j], dtype=np.float64)) for j in range(J)]
        v_posed = v_shaped[t].copy()
        if posedirs is not None and len(posedirs):
            feat = np.concatenate([(rots[j] - np.eye(3)).ravel() for j in range(1, J)])
            v_posed += (feat @ np.asarray(posedirs, np.float64)).reshape(V, 3)
        world = []
        for j in range(J):
            local = np.eye(4)
            local[:3, :3] = rots[j]
            local[:3, 3] = joints[j] - (joints[parents[j]] if parents[j] >= 0 else 0.0)
            world.append(local if parents[j] < 0 else world[parents[j]] @ local)
        for j in range(J):
            to_rest = np.eye(4)
            to_rest[:3, 3] = -joints[j]
            a = world[j] @ to_rest
            a[:3, 3] += translation[t]
            out_a[t, j] = a
        blended = np.einsum("vj,jab->vab", W, out_a[t])
        homo = np.concatenate([v_posed, np.ones((V, 1))], axis=1)
        out_v[t] = np.einsum("vab,vb->va", blended, homo)[:, :3]
    return out_v, out_a


# ---------------------------------------------------------------------------------------------
# torch twin

def axis_angle_to_matrix_torch(aa):
    """Rodrigues in torch, (..., 3) -> (..., 3, 3), with finite gradients at zero rotation.

    sin(t)/t and (1 - cos t)/t^2 switch to their Taylor series below 1e-4, where both branches
    agree to float precision, so neither the value nor the gradient sees a 0/0.
    """
    import torch

    theta2 = (aa * aa).sum(-1)
    small = theta2 < 1e-8
    safe2 = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(safe2)
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / safe2)
    x, y, z = aa.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(aa.shape[:-1] + (3, 3))
    eye = torch.eye(3, dtype=aa.dtype, device=aa.device).expand(K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def lbs_torch(v_shaped, J_regressor, parents, weights, pose, translation, posedirs=None):
    """`lbs` in torch. v_shaped (T, V, 3), J_regressor (J, V) dense tensor, weights (V, J),
    pose (T, J, 3), translation (T, 3), posedirs (9 (J-1), V*3) or None -> (T, V, 3), (T, J, 4, 4)."""
    import torch

    T, V, _ = v_shaped.shape
    J = len(parents)
    joints = torch.einsum("jv,tvc->tjc", J_regressor, v_shaped)
    rot = axis_angle_to_matrix_torch(pose.reshape(T, J, 3))
    v_posed = v_shaped
    if posedirs is not None and posedirs.numel():
        eye = torch.eye(3, dtype=rot.dtype, device=rot.device)
        feat = (rot[:, 1:] - eye).reshape(T, -1)
        v_posed = v_shaped + (feat @ posedirs).reshape(T, V, 3)
    rel = torch.cat([joints[:, :1], joints[:, 1:] - joints[:, list(parents[1:])]], dim=1)
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=rot.dtype, device=rot.device).expand(T, J, 1, 4)
    local = torch.cat([torch.cat([rot, rel[..., None]], dim=-1), bottom], dim=-2)  # (T, J, 4, 4)
    world = [local[:, 0]]
    for j in range(1, J):
        world.append(world[int(parents[j])] @ local[:, j])
    world = torch.stack(world, dim=1)
    shift = torch.einsum("tjab,tjb->tja", world[..., :3, :3], joints)
    trans = world[..., :3, 3] - shift + translation[:, None, :]
    A = torch.cat([torch.cat([world[..., :3, :3], trans[..., None]], dim=-1), bottom], dim=-2)
    M = torch.einsum("vj,tjk->tvk", weights, A[:, :, :3, :].reshape(T, J, 12)).reshape(T, V, 3, 4)
    verts = torch.einsum("tvab,tvb->tva", M[..., :3], v_posed) + M[..., 3]
    return verts, A

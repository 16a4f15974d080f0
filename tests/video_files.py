"""Writers of small files in the exact layouts video pose pipelines save (test helpers).

Each ``write_<format>`` takes a z-up ground-truth :class:`Motion` (from ``motion_arrays``),
expresses it in the pipeline's own frame and layout (the inverse of what the readers do) and
writes the file as the pipeline does (pickle, joblib stream, torch.save, np.save, np.savez).
``joblib_dumps`` writes joblib's stream format (NumpyArrayWrapper + in-stream array bytes)
without joblib.
"""

from __future__ import annotations

import pickle
import zlib
from collections import OrderedDict, defaultdict
from pathlib import Path

import numpy as np
import torch

from mdvae_cli.body.builtin import builtin_body_model
from mdvae_cli.formats.data_write import pickle_bytes
from mdvae_cli.formats.npz_io import motion_from_arrays
from mdvae_cli.formats.video_tracks import CAMERA_UP, Y_UP, rest_pelvis, up_to_z
from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat
from mdvae_cli.geometry.rotations_np import rotmat_to_rotvec as np_rotmat_to_rotvec
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat as np_rotvec_to_rotmat
from mdvae_cli.motion.motion import Motion

BODY = builtin_body_model()


def clip(T: int = 40, seed: int = 0, fps: float = 30.0) -> Motion:
    """A smooth upright clip (``conftest.motion_arrays`` stood up: z up), SMPL layout."""
    from conftest import motion_arrays

    arrays = motion_arrays(T=T, width=72, fps=fps, seed=seed, num_betas=10)
    upright = _mat([np.pi / 2, 0.0, 0.0]) @ _mat(arrays["poses"][:, :3])  # stand on z = 0
    arrays["poses"][:, :3] = _vec(upright)
    return motion_from_arrays(arrays)


def _mat(rv):
    return rotvec_to_rotmat(torch.as_tensor(np.asarray(rv, np.float64))).numpy()


def _vec(m):
    return rotmat_to_rotvec(torch.as_tensor(np.asarray(m, np.float64))).numpy()


def to_source(motion: Motion, up, pelvis: bool = False):
    """The motion's root (T, 3, 3) and translation in a frame whose up is ``up``: the inverse
    of ``video_tracks.track_to_motion``. pelvis: return the pelvis position instead of the
    body model's translation."""
    C = up_to_z(up)
    J0 = rest_pelvis(BODY, motion.betas)
    root = C.T @ _mat(motion.root_orient)
    p = (motion.trans + J0) @ C  # C^T applied to each row
    return root, (p if pelvis else p - J0)


def smpl72(root_mat, motion: Motion) -> np.ndarray:
    """(T, 72) SMPL axis-angles: root, the 21 body joints, the two hand joints."""
    T = motion.num_frames
    return np.concatenate(
        [_vec(root_mat), motion.pose_body.reshape(T, 63), motion.pose_extra[:, :6]], 1
    ).astype(np.float32)


def smpl_mats(root_mat, motion: Motion) -> np.ndarray:
    """(T, 24, 3, 3) SMPL rotation matrices."""
    T = motion.num_frames
    rest = _mat(np.concatenate([motion.pose_body, motion.pose_extra[:, :6].reshape(T, 2, 3)], 1))
    return np.concatenate([root_mat[:, None], rest], 1).astype(np.float32)


# --------------------------------------------------------------------------------------------
# joblib's stream format


def joblib_dumps(obj, compress: bool = False, align: bool = True) -> bytes:
    """``joblib.dump``'s bytes (the product's writer, ``formats.data_write``): arrays padded
    to 16 bytes, or unpadded (``align`` False, older joblib); zlib-compressed with
    ``compress``."""
    data = pickle_bytes(obj, joblib=True, alignment=16 if align else None)
    return zlib.compress(data, 3) if compress else data


# --------------------------------------------------------------------------------------------
# the pipelines


def write_wham(path: Path, tracks: dict, world: bool = True) -> Path:
    """tracks: {track id: (motion, frame_ids or None)} -> wham_output.pkl (joblib)."""
    out = defaultdict(dict)
    for tid, (m, ids) in tracks.items():
        T = m.num_frames
        root_w, trans_w = to_source(m, Y_UP)
        root_c, trans_c = to_source(m, CAMERA_UP)
        d = {
            "pose": smpl72(root_c, m),
            "trans": trans_c.astype(np.float32),
            "betas": np.tile(m.betas, (T, 1)).astype(np.float32),
            "verts": np.zeros((T, 5, 3), np.float32),
            "frame_ids": np.arange(T) if ids is None else np.asarray(ids),
        }
        if world:
            d.update(pose_world=smpl72(root_w, m), trans_world=trans_w.astype(np.float32))
        out[np.int64(tid)] = d
    path.write_bytes(joblib_dumps(out))
    return path


def write_gvhmr(path: Path, m: Motion) -> Path:
    """hmr4d_results.pt: torch.save of SMPL-X params, global (y up) and in camera."""
    T = m.num_frames

    def params(up):
        root, transl = to_source(m, up)
        return {
            "body_pose": torch.tensor(m.pose_body.reshape(T, 63), dtype=torch.float32),
            "betas": torch.tensor(np.tile(m.betas, (T, 1)), dtype=torch.float32),
            "global_orient": torch.tensor(_vec(root), dtype=torch.float32),
            "transl": torch.tensor(transl, dtype=torch.float32),
        }

    pred = {
        "smpl_params_global": params(Y_UP),
        "smpl_params_incam": params(CAMERA_UP),
        "K_fullimg": torch.eye(3).expand(T, 3, 3).clone(),
        "net_outputs": OrderedDict(pred_x=torch.zeros(1, T, 151)),
    }
    torch.save(pred, path)
    return path


def write_hybrik(path: Path, m: Motion) -> Path:
    """res.pk: plain pickle; 24 rotation matrices, transl = the pelvis in the camera frame."""
    T = m.num_frames
    root, pelvis = to_source(m, CAMERA_UP, pelvis=True)
    res = {
        "pred_thetas": smpl_mats(root, m).reshape(T, 216),
        "pred_betas": np.tile(m.betas, (T, 1)).astype(np.float32),
        "transl": pelvis.astype(np.float32),
        "pred_cam_root": pelvis.astype(np.float32),
        "pred_xyz_29": np.zeros((T, 29, 3), np.float32),
        "img_path": np.array([f"img_{i:06d}.png" for i in range(T)]),
        "bbox": np.zeros((T, 4)),
    }
    path.write_bytes(pickle.dumps(res, protocol=4))
    return path


def write_tram(folder: Path, m: Motion, with_camera: bool = True) -> Path:
    """results/<video>/hps/hps_track_0.npy (dict of tensors) and, optionally, camera.npy with
    a world transform (y up world) per video frame."""
    T = m.num_frames
    rng = np.random.default_rng(1)
    Rw = _mat(rng.normal(0, 0.3, size=(T, 3)))  # camera-to-world, per frame
    tw = rng.normal(0, 1.0, size=(T, 3))
    root_w, trans_w = to_source(m, Y_UP)
    J0 = rest_pelvis(BODY, m.betas)
    # world = Rw @ cam + tw for the pelvis and the root
    pelvis_c = np.einsum("tji,tj->ti", Rw, trans_w + J0 - tw)
    root_c = np.transpose(Rw, (0, 2, 1)) @ root_w
    if not with_camera:
        root_c, trans_c = to_source(m, CAMERA_UP)
        pelvis_c = trans_c + J0
    hps = {
        "pred_rotmat": torch.tensor(smpl_mats(root_c, m)),
        "pred_shape": torch.tensor(np.tile(m.betas, (T, 1)), dtype=torch.float32),
        "pred_trans": torch.tensor((pelvis_c - J0)[:, None], dtype=torch.float32),
        "pred_cam": torch.zeros(T, 3),
        "frame": torch.arange(T),
    }
    (folder / "hps").mkdir(parents=True, exist_ok=True)
    np.save(folder / "hps" / "hps_track_0.npy", hps, allow_pickle=True)
    if with_camera:
        cam = {
            "world_cam_R": Rw.astype(np.float32),
            "world_cam_T": tw.astype(np.float32),
            "img_focal": np.float32(1000),
        }
        np.save(folder / "camera.npy", cam, allow_pickle=True)
    return folder / "hps" / "hps_track_0.npy"


def write_phalp(path: Path, tracks: dict) -> Path:
    """demo_<video>.pkl: zlib-compressed joblib stream of {frame name: per-person lists}."""
    T = max(max(ids) for _, ids in tracks.values()) + 1
    per = {}
    for tid, (m, _) in tracks.items():
        root, transl = to_source(m, CAMERA_UP)
        per[tid] = (smpl_mats(root, m), transl)
    frames = {}
    for t in range(T):
        f = {
            "time": t,
            "shot": 0,
            "frame_path": f"img/{t:06d}.jpg",
            "tid": [],
            "smpl": [],
            "camera": [],
            "bbox": [],
        }
        for tid, (m, ids) in tracks.items():
            if t in ids:
                i = list(ids).index(t)
                mats, transl = per[tid][0][i], per[tid][1]
                f["tid"].append(tid)
                f["smpl"].append(
                    {
                        "global_orient": mats[:1],
                        "body_pose": mats[1:],
                        "betas": m.betas.astype(np.float32),
                    }
                )
                f["camera"].append(transl[i].astype(np.float32))
                f["bbox"].append(np.zeros(4))
        frames[f"img/{t:06d}.jpg"] = f
    path.write_bytes(joblib_dumps(frames, compress=True))
    return path


def write_vibe(path: Path, m: Motion, matrices: bool = False, ids=None) -> Path:
    """vibe_output.pkl / pare_output.pkl (joblib): pose axis-angles (VIBE) or matrices (PARE),
    orig_cam, no translation; ``ids``: the frame ids of m's frames (default 0, 1, ...)."""
    T = m.num_frames
    root, _ = to_source(m, CAMERA_UP)
    pose = smpl_mats(root, m) if matrices else smpl72(root, m)
    d = {
        1: {
            "pose": pose,
            "betas": np.tile(m.betas, (T, 1)).astype(np.float32),
            "orig_cam": np.tile([0.5, 0.5, 0.1, -0.2], (T, 1)).astype(np.float32),
            "pred_cam": np.zeros((T, 3), np.float32),
            "frame_ids": np.arange(T) if ids is None else np.asarray(ids),
            "joints3d": np.zeros((T, 49, 3), np.float32),
        }
    }
    path.write_bytes(joblib_dumps(d))
    return path


def write_romp(path: Path, tracks: dict) -> Path:
    """video_results.npz: np.savez of object arrays; sequence_results {track: per-frame lists}."""
    seq = {}
    for tid, (m, ids) in tracks.items():
        root, transl = to_source(m, CAMERA_UP)
        p = smpl72(root, m)
        seq[tid] = {
            "frame_id": list(ids),
            "global_orient": list(p[:, :3]),
            "body_pose": list(p[:, 3:]),
            "smpl_betas": list(np.tile(m.betas, (len(p), 1))),
            "cam_trans": list(transl.astype(np.float32)),
            "cam": list(np.zeros((len(p), 3))),
        }
    np.savez(path, results={"frame.jpg": {}}, sequence_results=seq)
    return path


def write_slahmr(path: Path, motions: list[Motion]) -> Path:
    """<seq>_world_results.npz: plain npz, B tracks, SMPL-H hands, a floor plane; its world is
    a camera frame (y down), so up = -y."""
    roots, trans = zip(*(to_source(m, CAMERA_UP) for m in motions), strict=True)
    T = motions[0].num_frames
    np.savez(
        path,
        root_orient=np.stack([_vec(r) for r in roots]).astype(np.float32),
        trans=np.stack(trans).astype(np.float32),
        pose_body=np.stack([m.pose_body.reshape(T, 63) for m in motions]).astype(np.float32),
        pose_hand=np.zeros((len(motions), T, 90), np.float32),
        betas=np.stack([np.r_[m.betas, np.zeros(6)] for m in motions]).astype(np.float32),
        cam_R=np.tile(np.eye(3), (len(motions), T, 1, 1)),
        cam_t=np.zeros((len(motions), T, 3)),
        track_mask=np.ones((len(motions), T), bool),
        floor_plane=np.array([0.0, -1.2, 0.0], np.float32),
    )
    return path


def write_aistpp(path: Path, m: Motion, scale: float = 90.0) -> Path:
    root, transl = to_source(m, Y_UP)
    d = {
        "smpl_loss": 1.5,
        "smpl_poses": smpl72(root, m),
        "smpl_scaling": np.array([scale], np.float32),
        "smpl_trans": (transl * scale).astype(np.float32),
    }
    path.write_bytes(pickle.dumps(d, protocol=4))
    return path


def edited(m: Motion, every: int = 3) -> tuple[Motion, np.ndarray]:
    """``m`` with every ``every``-th frame turned 0.2 rad about z, moved 5 cm and one knee
    bent 0.1 rad more; -> (the copy, the frames changed)."""
    sel = np.arange(m.num_frames) % every == 0
    root, body, trans = m.root_orient.copy(), m.pose_body.copy(), m.trans.copy()
    root[sel] = np_rotmat_to_rotvec(np_rotvec_to_rotmat(np.array([0, 0, 0.2]))
                                 @ np_rotvec_to_rotmat(root[sel]))  # fmt: skip
    trans[sel] += [0.05, -0.03, 0.02]
    body[sel, 3, 0] += 0.1
    return m.with_body(root_orient=root, pose_body=body, trans=trans), sel


def same_rotations(a: np.ndarray, b: np.ndarray) -> float:
    """Largest angle (rad) between the rotations of two axis-angle arrays (..., 3)."""
    d = np_rotvec_to_rotmat(a.reshape(-1, 3)).transpose(0, 2, 1) @ np_rotvec_to_rotmat(
        b.reshape(-1, 3)
    )
    return float(np.abs(np_rotmat_to_rotvec(d)).max())

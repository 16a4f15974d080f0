"""A GVHMR result converted to an AMASS-style npz by a downstream project ("gvhmr-npz",
``formats.estimates``): ``poses`` / ``trans`` hold GVHMR's world motion, and the file keeps
GVHMR's camera-frame copy flattened into ``smpl_params_incam_{global_orient, body_pose,
betas, transl}`` and the network's internals into ``net_outputs_*``.

When the world motion is written back cleaned, its camera-frame copy follows it as that of a
GVHMR ``.pt`` does (``video_back.put_gvhmr``): per frame the file's own camera rotation
``R_c = R_incam R_world^T`` (both read from the file) takes the cleaned root and the
translation's change into the camera frame, the cleaned body joints are copied; every value
the cleaning left alone stays the file's own, bit for bit. The network's internals, made for
the old pose, are left out. The world motion as read is kept in ``Motion.layout`` (never
written) from reading to writing.
"""

from __future__ import annotations

import numpy as np

from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat
from mdvae_cli.motion.motion import Motion

#: ``Motion.layout`` key: (root_orient, pose_body, trans) of the world motion as read
WORLD_AS_READ = "gvhmr_world_as_read"
#: the flattened camera-frame copy's keys
INCAM = "smpl_params_incam_"
#: the flattened network internals' key prefix
NET_OUTPUTS = "net_outputs_"


def remember_world(motion: Motion) -> None:
    """Keep ``motion``'s world pose as read (in its layout) for :func:`camera_follows_world`."""
    motion.layout[WORLD_AS_READ] = (
        np.array(motion.root_orient, copy=True),
        np.array(motion.pose_body, copy=True),
        np.array(motion.trans, copy=True),
    )


def camera_follows_world(motion: Motion) -> tuple[Motion, list[str]]:
    """``motion`` (a cleaned gvhmr-npz motion) with its ``smpl_params_incam_*`` extras moved
    as its world pose was, and its ``net_outputs_*`` left out -> (motion, notes for the user).
    A motion not read from such a file comes back as it is, with no notes. Camera-frame copies
    whose rows do not match the frames as read (e.g. resampled) are left as they came, said
    in a note."""
    as_read = motion.layout.get(WORLD_AS_READ)
    if as_read is None:
        return motion, []
    out = motion.with_body()
    del out.layout[WORLD_AS_READ]
    notes: list[str] = []
    net = sorted(k for k in out.extras if k.startswith(NET_OUTPUTS))
    for k in net:
        del out.extras[k]
    if net:
        notes.append(f"{len(net)} '{NET_OUTPUTS}*' arrays left out (the network's internals "
                     "for the old pose)")  # fmt: skip
    root0, body0, trans0 = as_read
    keys = [INCAM + k for k in ("global_orient", "transl")]
    if not all(k in out.extras for k in keys):
        return out, notes
    T = len(root0)
    go, tr = (np.asarray(out.extras[k]) for k in keys)
    bp = out.extras.get(INCAM + "body_pose")
    shapes = [go.shape[:1], tr.shape[:1], () if bp is None else np.shape(bp)[:1]]
    if out.num_frames != T or any(s not in ((T,), ()) for s in shapes) or go.size != 3 * T:
        notes.append(f"the camera-frame copies ('{INCAM}*') are left as they came: their "
                     "frames are not the motion's")  # fmt: skip
        return out, notes
    from mdvae_cli.formats.video_rows import camera_follows, file_rows, put_body
    from mdvae_cli.formats.video_tracks import RawTrack

    raw = RawTrack(root=rotvec_to_rotmat(np.asarray(root0, np.float64)), body=body0,
                   transl=trans0, betas=out.betas, up=(0.0, 0.0, 1.0))  # fmt: skip
    before = out.with_body(root_orient=root0, pose_body=body0, trans=trans0)
    rows = file_rows(raw, before, out)
    go_new, tr_new = camera_follows(go, tr, raw.root, rows)
    out.extras[keys[0]], out.extras[keys[1]] = go_new, tr_new
    if bp is not None and np.shape(bp)[1:] in ((63,), (21, 3)):
        out.extras[INCAM + "body_pose"] = put_body(bp, rows)
    return out, notes

"""Windows back into motions: each motion's denoised windows stitched into one sequence at
30 Hz (overlaps cross-faded: slerp on rotations, lerp on translation), then put back at the
file's own frame times (``infer.native_rate.to_input_rate``) in a copy of the input motion."""

from __future__ import annotations

import torch

from mdvae_cli.geometry.rotations import quat_slerp, quat_to_rotvec, rotvec_to_quat
from mdvae_cli.infer.native_rate import to_input_rate
from mdvae_cli.infer.window_groups import WindowGroup
from mdvae_cli.model.state import BodyParams
from mdvae_cli.motion.motion import Motion


def blend_windows(num_frames: int, starts: list[int], windows: list[BodyParams]) -> BodyParams:
    """Stitch windows (each (L, ...)) into one (T, ...) sequence; overlaps cross-fade linearly
    (slerp for rotations) from the earlier window to the later one.

    Rotations are blended as quaternions, converted once for all windows and once back."""
    order = sorted(range(len(starts)), key=lambda i: starts[i])
    rot = [torch.cat([w.root_orient[:, None], w.pose_body], dim=1) for w in windows]
    lengths = {r.shape[0] for r in rot}
    if len(lengths) == 1:  # one conversion for every window
        quats = list(rotvec_to_quat(torch.stack(rot)).unbind(0))
    else:
        quats = [rotvec_to_quat(r) for r in rot]
    q = torch.zeros(num_frames, 22, 4, dtype=quats[0].dtype)
    trans = torch.zeros(num_frames, 3)
    written = 0
    for i in order:
        s, wq, wt = starts[i], quats[i], windows[i].trans
        L = wt.shape[0]
        ov = max(0, min(written - s, L))
        if ov:
            a = torch.arange(1, ov + 1, dtype=torch.float32) / (ov + 1)
            sl = slice(s, s + ov)
            q[sl] = quat_slerp(q[sl], wq[:ov], a[:, None].to(q.dtype))
            trans[sl] = trans[sl] * (1 - a[:, None]) + wt[:ov] * a[:, None]
        q[s + ov : s + L] = wq[ov:]
        trans[s + ov : s + L] = wt[ov:]
        written = max(written, s + L)
    rotvecs = quat_to_rotvec(q).to(windows[0].pose_body.dtype)
    return BodyParams(rotvecs[:, 0], rotvecs[:, 1:], trans)


def assemble(
    motions: list[Motion],
    motions30: list[Motion],
    groups: list[WindowGroup],
    predictions: list[BodyParams],
) -> list[Motion]:
    """Blend every motion's windows and write the results into copies of the input motions."""
    per_motion: dict[int, list[tuple[int, BodyParams]]] = {}
    for g, pred in zip(groups, predictions, strict=True):
        for k, (mi, s) in enumerate(g.owners):
            one = BodyParams(pred.root_orient[k], pred.pose_body[k], pred.trans[k])
            per_motion.setdefault(mi, []).append((s, one))
    out = []
    for mi, (motion, m30) in enumerate(zip(motions, motions30, strict=True)):
        items = per_motion[mi]
        p30 = blend_windows(m30.num_frames, [s for s, _ in items], [w for _, w in items])
        p = to_input_rate(p30, motion)
        out.append(
            motion.with_body(
                root_orient=p.root_orient.double().numpy(),
                pose_body=p.pose_body.double().numpy(),
                trans=p.trans.double().numpy(),
            )
        )
    return out

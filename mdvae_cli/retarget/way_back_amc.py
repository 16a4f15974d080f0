"""The way back for ASF/AMC takes: a cleaned SMPL motion onto the take's own skeleton.

As for BVH (``retarget.way_back``): each bone that drives an SMPL joint turns by the same
world-space change as that joint did after cleaning, ``G'_b = D_j G_b``, from the file's own
rotations; bones the SMPL proxy does not cover (fingers, thumbs, hip joints, a lower back, toes
or clavicles nothing drives) keep their values and follow their parent; the root moves as the
SMPL pelvis did, in the file's length unit and axes. A bone that no SMPL joint's rotation
follows but that carries an SMPL joint's point (a thorax between two driven spine bones, when
two SMPL spine joints share one source bone) turns the least it can to take that point where
the SMPL joint went (on CMU's noisy takes: 1.4 mm closer on 05_01, unchanged elsewhere),
except where its parent was turned for one frame (a spike filled): there the point's move is
the retarget's miss of the turned joint, and the bone keeps its world rotation in the share it
did not jump with its parent, as a bone that carries nothing does (``steady.below_brief_turn``).

An ASF bone can only turn about its own ``dof`` axes, so its values are solved for its new
rotation (``retarget.dof_solve``), nearest to the file's values:

* three rotation dofs reach any rotation exactly (Euler angles in the bone's frame, the branch
  nearest the file's values);
* fewer (a knee's ``dof rx``, a foot's ``rx rz``, a clavicle's ``ry rz``) take the closest
  rotation their axes can express (the smallest residual turn); the bones above it that no SMPL
  joint drives, up to the next driven one (CMU's ``lradius`` below the driven ``lwrist``),
  share the turn, so an elbow bend the cleaning changed goes to the bone that bends. Each bone
  below is solved against where its parent really ended up, so what one bone cannot express
  the next may take up.
* the root's translation follows the cleaned pelvis on the channels the file has (a component
  without a channel keeps the file's value).
"""

from __future__ import annotations

import math

import numpy as np

from mdvae_cli.errors import InputError
from mdvae_cli.formats.asfamc import AmcLayout, dof_rotation, rotation_columns
from mdvae_cli.formats.source import SourceMotion
from mdvae_cli.geometry.euler import rotmat_to_euler
from mdvae_cli.geometry.kinematics import forward_kinematics
from mdvae_cli.geometry.rotations_np import rotmat_between
from mdvae_cli.motion.motion import Motion
from mdvae_cli.retarget.dof_solve import axis_rotations, closest_angles
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.held_channels import constant_channels
from mdvae_cli.retarget.steady import below_brief_turn, miss_jitter
from mdvae_cli.retarget.way_back import (
    driven_rotations,
    drivers,
    pelvis_point,
    smpl_change,
    smpl_globals,
)


def _unit(layout: AmcLayout) -> float:
    """Radians per file angle unit."""
    return math.pi / 180.0 if layout.degrees else 1.0


def _bone(src: SourceMotion, j: int) -> str | None:
    """The AMC name of source joint j ("root", a bone), or None for a bone tip."""
    return None if src.end_site[j] else src.names[j]


def _listed(layout: AmcLayout, name: str | None) -> list[tuple[int, str]]:
    """(column, axis) of the rotation dofs of ``name`` that the file writes."""
    if name is None or name not in layout.values:
        return []
    return rotation_columns(layout.dofs(name))


def amc_pose(src: SourceMotion, layout: AmcLayout, values: dict[str, np.ndarray]):
    """World-aligned local rotations (T, J, 3, 3), world rotations (T, J, 3, 3) and joint
    positions (T, J, 3; file units, ASF axes) of ``values`` (bone -> (T, n), the frames of
    ``src``), as :func:`~mdvae_cli.formats.asfamc.load_amc` reads them."""
    T, J = next(iter(values.values())).shape[0], src.num_joints
    L = np.broadcast_to(np.eye(3), (T, J, 3, 3)).copy()
    t = np.tile(src.offsets / layout.metres_per_unit, (T, 1, 1))
    sk = layout.skeleton
    t[:, 0] = sk.root_position
    root = values.get("root", np.zeros((T, len(sk.root_order))))
    for i, ch in enumerate(sk.root_order):
        if ch.startswith("t"):
            t[:, 0, "xyz".index(ch[1])] += root[:, i]
    for j in range(J):
        name = _bone(src, j)
        rot = _listed(layout, name)
        if rot:
            L[:, j] = _bone_rotation(layout, name, values[name][:, [c for c, _ in rot]])
    G, P = forward_kinematics(L, t, src.parents)
    return L, t, G, P


def _bone_rotation(layout: AmcLayout, name: str, values: np.ndarray) -> np.ndarray:
    """A bone's local rotations from its rotation dofs' values (n, k), file units, in listed
    order.  -> (n, 3, 3)"""
    rot = _listed(layout, name)
    return dof_rotation(layout.frame(name), values * _unit(layout), "".join(a for _, a in rot))


def _keep_below_brief_turn(src, layout, j, rotations, brief, drive, vals, new) -> None:
    """Bone j, not driven, where its parent was turned briefly (a spike filled: ``brief``
    (T, 22) of the body's joints, ``drive`` the bones' drivers) and it stayed put in the file:
    its world rotation kept in the share it did not jump with its parent
    (``steady.below_brief_turn``), its dofs solved for it there (fewer than three: as near
    it as they reach, ``_solve``), in place in ``new`` and ``L2``. rotations: the world
    rotations before and after (T, J, 3, 3) and the local ones after, filled down to j's
    parent."""
    G, G2, L2 = rotations
    rot = _listed(layout, src.names[j])
    if not rot:
        return  # a bone without rotation dofs cannot turn: it follows, as before
    t, Lt = below_brief_turn(G2, G, brief, drive, int(src.parents[j]), j)
    if not len(t):
        return
    v = _solve(src, layout, [j], Lt, {b: x[t] for b, x in vals.items()})[src.names[j]]
    new[src.names[j]][t[:, None], [c for c, _ in rot]] = v
    L2[t, j] = _bone_rotation(layout, src.names[j], v)


def _chain(src: SourceMotion, layout: AmcLayout, drive: np.ndarray, j: int) -> list[int]:
    """Bone j, and when it cannot turn freely (fewer than 3 rotation dofs) the undriven bones
    above it with one child each, up to the next driven one; top first."""
    chain = [j]
    if len(_listed(layout, _bone(src, j))) >= 3:
        return chain
    kids = np.bincount(src.parents[1:], minlength=src.num_joints)
    p = int(src.parents[j])
    while p > 0 and drive[p] < 0 and kids[p] == 1:
        chain.insert(0, p)
        p = int(src.parents[p])
    return chain


def _solve(src, layout, chain, R, values) -> dict[str, np.ndarray]:
    """New file values of the chain's bones (name -> (T, k) in listed dof order, file units)
    whose rotations, composed top first, come closest to R (T, 3, 3), nearest ``values``.
    A dof that holds one value through the take (``held_channels``) keeps it: it is a fixed
    turn in the chain, and the other dofs come as close to R as they can around it."""
    unit = _unit(layout)
    parts = [(src.names[j], _listed(layout, src.names[j])) for j in chain]
    parts = [(name, rot) for name, rot in parts if rot]
    if not parts:
        return {}
    held = {name: constant_channels(values[name][:, [c for c, _ in rot]]) for name, rot in parts}
    if (len(parts) == 1 and len({a for _, a in parts[0][1]}) == 3 == len(parts[0][1])
            and not held[parts[0][0]].any()):  # fmt: skip
        name, rot = parts[0]  # three axes: Euler angles, exactly
        C = layout.frame(name)
        near = values[name][:, [c for c, _ in rot]][:, ::-1] * unit
        axes = "".join(a for _, a in rot)[::-1]
        angles = rotmat_to_euler(C.T @ R @ C, axes, near)[:, ::-1]
        return {name: angles / unit}
    # A = T_1 ... T_n, outermost first; a held turn F moved to the right of the free turns
    # after it turns their axes: F Rot(u, a) = Rot(F u, a) F, so A = (free turns) @ fixed
    axes, start, where, fixed = [], [], [], np.eye(3)
    out = {name: values[name][:, [c for c, _ in rot]].copy() for name, rot in parts}
    for name, rot in parts:  # outermost first: the last listed dof of the top bone
        C = layout.frame(name)
        for k in range(len(rot) - 1, -1, -1):
            u = C[:, "xyz".index(rot[k][1])]
            if held[name][k]:
                fixed = (
                    fixed @ axis_rotations(u[None], values[name][:1, rot[k][0], None] * unit)[0, 0]
                )
                continue
            axes.append(fixed @ u)
            start.append(values[name][:, rot[k][0]] * unit)
            where.append((name, k))
    if not axes:
        return out
    angles = closest_angles(R @ fixed.T, np.array(axes), np.stack(start, axis=1))
    for i, (name, k) in enumerate(where):
        out[name][:, k] = angles[:, i] / unit
    return out


def held_bones(layout: AmcLayout, values: dict[str, np.ndarray]) -> set[str]:
    """The bones whose rotation dofs hold one value through the take (``held_channels``: a
    CMU clavicle's two dofs at 0), or that have none: the way back leaves them as they came,
    and the bones below take up the turn the cleaning asked of them.  values: bone -> (T, n)."""
    out = set()
    for name, v in values.items():
        rot = _listed(layout, name)
        if not rot or constant_channels(v[:, [c for c, _ in rot]]).all():
            out.add(name)
    return out


def _carried(rt, src, layout, drive, motions, body, P, G, moved, w) -> dict:
    """Bones no SMPL joint drives that carry an SMPL joint's point (CMU's lowerback carries
    spine1): bone -> (the point's offset in the bone's frame (T, 3), where it should go (T, 3),
    before the root's final ``moved`` (T, 3)), file units: it moves as the SMPL joint did,
    from the course of the retarget's miss of it where the cleaning turned the body (``w``
    (T,): the largest of the joints' ``steady.turn_reading`` weight, :func:`miss_jitter`), as the
    pelvis does."""
    M = np.asarray(rt.to_output)
    scale = layout.metres_per_unit
    jm = rt.jmap
    out = {}
    Po = Pc = None
    for k in range(len(jm.attach)):
        j = int(jm.attach[k])
        if jm.direct[k] or j <= 0 or drive[j] >= 0 or j in out:
            continue
        if not _listed(layout, _bone(src, j)):
            continue
        if Po is None:
            Po, Pc = (smpl_globals(m, body)[1] for m in motions)
        target = ((rt.targets[:, k] + rt.drop) @ M) / scale
        local = (np.swapaxes(G[:, j], -1, -2) @ (target - P[:, j])[..., None])[..., 0]
        if np.linalg.norm(local, axis=-1).min() < 1e-6:
            continue  # the point sits on the joint: turning cannot move it
        move = Pc[:, k] - Po[:, k]
        move += miss_jitter(Po[:, k], rt.targets[:, k], w, src.fps)
        out[j] = (local, target + move @ M / scale - moved)
    return out


def write_back_amc(
    src: SourceMotion, rt, original: Motion, cleaned: Motion, body: BodyJoints
) -> dict[str, np.ndarray]:
    """The file's values (bone -> (F, n), every frame of the file) with the change from
    ``original`` to ``cleaned`` (SMPL motions of the frames of ``src``) carried onto the
    take's own skeleton.  rt: the :class:`RetargetResult` of ``src``."""
    layout = src.layout
    if not isinstance(layout, AmcLayout):
        raise InputError("this motion was not read from an AMC file; it cannot be written back")
    rows = layout.rows
    vals = {b: v[rows] for b, v in layout.values.items()}
    T = len(rows)
    if original.num_frames != T or cleaned.num_frames != T:
        raise InputError(f"the SMPL motions have {cleaned.num_frames} frames, the file {T}")
    scale = layout.metres_per_unit
    change = smpl_change(rt, original, cleaned, body, scale)
    L, t, G, P = amc_pose(src, layout, vals)
    drive = drivers(rt.jmap, src.num_joints)
    driven = driven_rotations(change, G, drive, src.fps)
    a = int(rt.jmap.anchor["pelvis"])
    new_a = pelvis_point(rt, change, P[:, a], scale, src.fps)
    carried = _carried(rt, src, layout, drive, (original, cleaned), body, P, G, new_a - P[:, a],
                       change.weight.max(axis=1))  # fmt: skip
    new = {b: v.copy() for b, v in vals.items()}
    L2, G2, P2 = L.copy(), G.copy(), P.copy()
    held = held_bones(layout, vals)
    for j in range(src.num_joints):
        p = int(src.parents[j])
        chain, R = [j], None
        if drive[j] >= 0:
            chain = _chain(src, layout, drive, j)
            R = driven[:, j]
            top = int(src.parents[chain[0]])
            if top >= 0:
                R = np.swapaxes(G2[:, top], -1, -2) @ R
        elif j in carried and a == 0:  # the root's move is known: points can be placed
            G2[:, j] = G2[:, p] @ L2[:, j]
            P2[:, j] = P2[:, p] + (G2[:, p] @ t[:, j, :, None])[..., 0]
            local, want = carried[j]
            S = rotmat_between((G2[:, j] @ local[..., None])[..., 0], want - P2[:, j])
            R = np.swapaxes(G2[:, p], -1, -2) @ S @ G2[:, j]
        if R is not None and all(src.names[k] in held or not _listed(layout, src.names[k])
                                 for k in chain):  # fmt: skip
            R = None  # angles held through the whole take come back as they came
        if R is not None:
            for name, v in _solve(src, layout, chain, R, vals).items():
                rot = _listed(layout, name)
                new[name][:, [c for c, _ in rot]] = v
                L2[:, src.index(name)] = _bone_rotation(layout, name, v)
        if p >= 0 and drive[j] < 0 and src.names[j] not in held and (j not in carried or a == 0):
            # under a brief turn of its parent, a bone that stayed put in the file keeps its
            # world rotation there (a carried one too: its point's move on that frame is the
            # retarget's miss of the turned joint, not the file's)
            _keep_below_brief_turn(src, layout, j, (G, G2, L2), change.brief, drive, vals, new)
        for k in chain:
            q = int(src.parents[k])
            if q >= 0:
                G2[:, k] = G2[:, q] @ L2[:, k]
                P2[:, k] = P2[:, q] + (G2[:, q] @ t[:, k, :, None])[..., 0]
            else:
                G2[:, k] = L2[:, k]

    moved = new_a - P2[:, a]
    if "root" in new:
        for i, ch in enumerate(layout.skeleton.root_order):
            if ch.startswith("t"):
                new["root"][:, i] += moved[:, "xyz".index(ch[1])]
    out = {b: v.copy() for b, v in layout.values.items()}
    for b, v in new.items():
        if not np.all(np.isfinite(v)):
            raise InputError(f"the way back gave non-finite values for bone {b}")
        out[b][rows] = v
    return out

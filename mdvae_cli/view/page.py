"""``mdvae view``'s page: motions posed in Python, embedded compactly in one self-contained
HTML file that plays them side by side or overlaid (``viewer_*.js`` draw them on a canvas).

What goes in, per motion (:func:`encode_track`):

* the root joint's world position, int32 mm (any take fits: it may wander 2,000 km);
* the pose (:func:`~mdvae_cli.view.pose.rotation_channels`): the root's world quaternion and
  each joint's local quaternion (x, y, z; w >= 0 implied), int16 in steps of 1/2048
  (~0.03 degrees), or of up to 1/256 in a channel whose own noise is far coarser
  (:func:`rotation_scales`: a noisy take's noise is not worth its bits); the page rebuilds
  the joints by forward kinematics from the rest joints;
* foot contacts (:func:`~mdvae_cli.motion.contacts.foot_contacts`), 4 bits a frame;
* the frames with a joint missing in the file (``joint_mask``), as runs: the page shades them
  on the plot ("filled": what ``mdvae denoise`` filled, or will fill);
* the rest joints and, unless ``mesh=False``, the decimated rest mesh
  (:mod:`mdvae_cli.view.mesh`) for its body shape.

Every array is delta-coded along time and deflated (:mod:`mdvae_cli.view.encode`): a
10-minute 30 Hz take is 1-2 MB (docs/benchmarks.md). Motions keep their own frames and rates;
the page aligns them by time.
"""

from __future__ import annotations

import html
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mdvae_cli import __version__
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import write_atomic
from mdvae_cli.formats.npz_holes import AS_READ
from mdvae_cli.infer.input_noise import noise_variance
from mdvae_cli.motion.contacts import (
    FOOT_JOINTS,
    HEIGHT_TOL,
    SPEED_MAX,
    foot_contacts,
    foot_floor_levels,
)
from mdvae_cli.motion.motion import Motion
from mdvae_cli.view.encode import Blob, encode_array, quantise
from mdvae_cli.view.mesh import SkinMesh, body_weights, decimate_body
from mdvae_cli.view.pose import (
    BEND_CHILD,
    BODY_JOINT_NAMES,
    BODY_PARENTS,
    PosedSkeleton,
    pose_skeleton,
    rotation_channels,
)

#: colours of the motions, in the order given (the first is usually the noisy one)
#: one colour per motion (the page's and the figure's), twelve apart before any repeats
PALETTE = ("#d9480f", "#1c7ed6", "#2b8a3e", "#9c36b5", "#e8a33d", "#0c8599", "#c2255c",
           "#8d5524", "#343a40", "#74b816", "#f783ac", "#4263eb")  # fmt: skip
#: integer units of the embedded arrays: positions in mm, quaternion components in 1/2048
POS_SCALE = 1000
ROT_SCALE = 2048
#: a rotation channel's step stays under 1/NOISE_STEPS of its own noise's standard deviation
#: (``infer.input_noise.noise_variance``), and is 1/ROT_SCALE to 1/MIN_ROT_SCALE
NOISE_STEPS = 16
MIN_ROT_SCALE = 256
_ASSETS = Path(__file__).resolve().parent
#: the page's script, in order; the parts share one function scope
SCRIPT_PARTS = ("viewer_data.js", "viewer_scene.js", "viewer_plot.js", "viewer_app.js")


@dataclass
class ViewPage:
    """A built page: ``html`` and what went into it (for summaries and tests)."""

    html: str
    mesh: bool
    motions: list[dict] = field(default_factory=list)

    @property
    def num_bytes(self) -> int:
        return len(self.html.encode("utf-8"))


@dataclass
class EncodedTrack:
    """One motion's per-frame arrays as the page gets them, and what they came from.

    root, rot, contacts: the encoded root position (T, 3), rotations (T, 67) and contact bits
    (T, 1); rot_scales: (67,) each rotation channel's units (:func:`rotation_scales`); posed:
    the posed skeleton; contacts_bool: (T, 4) the contacts as booleans.
    """

    root: Blob
    rot: Blob
    rot_scales: np.ndarray
    contacts: Blob
    posed: PosedSkeleton
    contacts_bool: np.ndarray

    def blobs(self) -> dict[str, Blob]:
        return {"root": self.root, "rot": self.rot, "contacts": self.contacts}


def rotation_scales(channels: np.ndarray) -> np.ndarray:
    """Each rotation channel's integer units per quaternion unit: ROT_SCALE, halved while the
    step stays under 1/NOISE_STEPS of the channel's own noise (its white-noise standard
    deviation from third differences in time), down to MIN_ROT_SCALE.

    channels: (T, C) :func:`~mdvae_cli.view.pose.rotation_channels` -> (C,) int"""
    sd = np.sqrt(noise_variance(channels))
    halvings = np.floor(np.log2(np.maximum(sd * ROT_SCALE / NOISE_STEPS, 1.0)))
    return np.maximum(ROT_SCALE >> halvings.astype(np.int64), MIN_ROT_SCALE)


def encode_track(motion: Motion, body: BodyModel) -> EncodedTrack:
    """Pose ``motion`` with ``body``, find its foot contacts, quantise and encode."""
    posed = pose_skeleton(motion, body)
    contacts = foot_contacts(posed.joints, motion.fps)
    bits = (contacts * (1 << np.arange(len(FOOT_JOINTS)))).sum(axis=1).astype(np.uint8)
    channels = rotation_channels(motion)
    scales = rotation_scales(channels)
    return EncodedTrack(
        root=encode_array(quantise(posed.joints[:, 0], 1 / POS_SCALE, "int32")),
        rot=encode_array(quantise(channels, 1 / scales, "int16")),
        rot_scales=scales,
        contacts=encode_array(bits[:, None], delta=False),
        posed=posed,
        contacts_bool=contacts,
    )


def sole_offsets(body: BodyModel) -> np.ndarray:
    """How high each foot joint sits above the sole in the rest pose, metres.  -> (4,)"""
    data = body.data
    part = body_weights(data).argmax(axis=1)
    feet = np.isin(part, FOOT_JOINTS)
    rest = np.asarray(data.J_regressor) @ np.asarray(data.v_template)
    sole = float(np.asarray(data.v_template)[feet, 1].min())  # SMPL rest pose is y-up
    return rest[list(FOOT_JOINTS), 1] - sole


def floor_height(posed_joints: Sequence[np.ndarray], offsets: np.ndarray) -> float:
    """Where to draw the floor: the lowest of the motions' floors, each the median over the foot
    joints of (their floor level - their height above the sole).  metres"""
    floors = [float(np.median(foot_floor_levels(J) - offsets)) for J in posed_joints]
    return min(floors)


def filled_runs(motion: Motion) -> list[list[int]]:
    """[start, stop) of each run of frames with a joint missing (``joint_mask`` False)."""
    if motion.joint_mask is None:
        return []
    hole = (~np.asarray(motion.joint_mask, bool)).any(axis=1).astype(np.int8)
    edges = np.diff(np.concatenate([[0], hole, [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [[int(a), int(b)] for a, b in zip(starts, stops, strict=True)]


def _round(values: np.ndarray, digits: int = 4) -> list:
    return np.round(np.asarray(values, dtype=np.float64), digits).reshape(-1).tolist()


def build_view_page(
    items: Sequence[tuple[str, Motion]],
    body: BodyModel,
    mesh: bool = True,
    title: str | None = None,
    skin: SkinMesh | None = None,
) -> ViewPage:
    """The page comparing ``items`` ((label, motion) pairs, drawn in this order and colour).

    mesh: embed the decimated body mesh (``skin``, default :func:`decimate_body` of ``body``)
    as well as the skeleton.
    """
    if not items:
        raise InputError("nothing to view: give at least one motion file")
    tracks = [encode_track(m, body) for _, m in items]
    skin = (skin or decimate_body(body.data)) if mesh else None
    offsets = sole_offsets(body)
    floor = floor_height([t.posed.joints for t in tracks], offsets)

    blobs: list[tuple[str, Blob]] = []
    motions_meta = []
    for i, ((name, motion), track) in enumerate(zip(items, tracks, strict=True)):
        described = {}
        for key, blob in track.blobs().items():
            element = f"m{i}-{key}"
            blobs.append((element, blob))
            described[key] = blob.describe(element)
        entry = {
            "name": name,
            "color": PALETTE[i % len(PALETTE)],
            "fps": motion.fps,
            "frames": motion.num_frames,
            "duration": motion.duration,
            "data": described,
            "rotation_scales": track.rot_scales.tolist(),
            "rest_joints": _round(track.posed.rest_joints),
            "contact_fraction": _round(track.contacts_bool.mean(axis=0), 3),
            "filled": filled_runs(motion),
            "missing_in_file": bool(motion.layout.get(AS_READ)),  # NaN rows: not filled
            "floor": round(floor_height([track.posed.joints], offsets), 4),
        }
        if skin is not None:
            entry["rest_vertices"] = _round(skin.rest_vertices(body.data, motion.betas))
        motions_meta.append(entry)

    meta = {
        "generator": f"mdvae {__version__}",
        "title": title or " vs ".join(name for name, _ in items),
        "joint_names": list(BODY_JOINT_NAMES),
        "parents": list(BODY_PARENTS),
        "bend_child": {str(k): v for k, v in BEND_CHILD.items()},
        "foot_joints": list(FOOT_JOINTS),
        "scales": {"position": POS_SCALE, "rotation": ROT_SCALE},
        "contact_rule": {"height_tol": HEIGHT_TOL, "speed_max": SPEED_MAX},
        "floor": round(floor, 4),
        "mesh": None,
        "motions": motions_meta,
    }
    if skin is not None:
        meta["mesh"] = {
            "faces": skin.faces.reshape(-1).tolist(),
            "joints": skin.joint_ids.reshape(-1).tolist(),
            "weights": _round(skin.joint_weights, 3),
            "influences": int(skin.joint_ids.shape[1]),
        }
    document = render_document(meta, blobs)
    summary = [
        {
            "name": name,
            "frames": m.num_frames,
            "fps": m.fps,
            "contact_fraction": e["contact_fraction"],
            "filled_frames": sum(b - a for a, b in e["filled"]),
        }
        for (name, m), e in zip(items, motions_meta, strict=True)
    ]
    return ViewPage(html=document, mesh=skin is not None, motions=summary)


def _script_json(data: dict) -> str:
    """JSON safe inside a <script> element (no '<' can close it)."""
    text = json.dumps(data, separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def render_document(meta: dict, blobs: Sequence[tuple[str, Blob]]) -> str:
    """The HTML text: style, controls, data elements and the viewer script, all inline."""
    parts = [(_ASSETS / name).read_text(encoding="utf-8") for name in SCRIPT_PARTS]
    script = (
        "/* mdvae view: plays the motions embedded in this page (no network, no libraries). */\n"
        '(function () {\n"use strict";\n' + "\n".join(parts) + "})();\n"
    )
    style = (_ASSETS / "viewer.css").read_text(encoding="utf-8")
    body = (_ASSETS / "viewer.html").read_text(encoding="utf-8")
    data = "\n".join(
        f'<script type="application/octet-stream" id="{element}">{blob.text}</script>'
        for element, blob in blobs
    )
    policy = (
        "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
        "img-src data: blob:"
    )
    return (
        '<!doctype html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f'<meta http-equiv="Content-Security-Policy" content="{policy}">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{html.escape(meta['title'])}</title>\n<style>\n{style}</style>\n</head>\n"
        f"<body>\n{body}\n"
        f'<script type="application/json" id="mdvae-meta">{_script_json(meta)}</script>\n'
        f"{data}\n<script>\n{script}</script>\n</body>\n</html>\n"
    )


def write_view_page(page: ViewPage, path: Path | str, forbid: Sequence[Path] = ()) -> None:
    """Write the page atomically (never onto a file in ``forbid``)."""
    path = Path(path)

    def write(tmp: Path) -> None:
        tmp.write_text(page.html, encoding="utf-8")

    write_atomic(path, write, forbid=forbid)


def write_before_after(
    noisy: Motion,
    cleaned: Motion,
    source: Path,
    output: Path,
    path: Path,
    body: BodyModel,
    forbid: Sequence[Path] = (),
) -> ViewPage:
    """``denoise --view``: the page of one input file (``source``) and its cleaned motion (in
    ``output``), written to ``path``."""
    names = [f"{Path(source).name} (input)", f"{Path(output).name} (cleaned)"]
    title = f"{Path(source).name}: before and after mdvae denoise"
    page = build_view_page(list(zip(names, (noisy, cleaned), strict=True)), body, title=title)
    write_view_page(page, path, forbid)
    return page

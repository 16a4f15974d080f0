"""The bad-input cases: every reader's defects, crossed with the file commands that read them.

A case is a defect (a bad file, the phrase its refusal must hold) run through one command.
The checks themselves are in ``test_bad_input.py``. Builders take the case folder (where a
pickle payload's marker file, :data:`MARKER`, would appear) and return the bad file's bytes.

Adding a reader (say a video pipeline's ``.pkl``) is a few rows:

1. the commands that read it, in :data:`COMMANDS` (a group name -> how each command takes the
   bad file, e.g. ``Command("denoise", lambda b, g, o: ["denoise", b, "-o", o / "c.npz"])``);
2. the reader -> that group in :data:`READER_COMMANDS`, and its file suffix in :data:`SUFFIXES`;
3. its defects, ``Defect("wham", "payload", lambda c: F.pickled(F.Payload(c / MARKER)),
   r"refusing to load")`` and so on, added to :data:`DEFECTS`; ``commands=ALL`` sends a
   defect through every command of the group, the rest go through the group's :data:`CORE`
   commands (all of them when it has none).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tests.bad_input import files as F

Builder = Callable[[Path], bytes]

#: the file a pickle payload creates in the case folder if any of its code runs
MARKER = "payload_ran"


@dataclass(frozen=True)
class Defect:
    """One bad file: ``build(case folder) -> bytes``, written as ``bad<suffix>``; ``expect``:
    a regular expression the error line must match (the problem, in the user's words)."""

    reader: str
    name: str
    build: Builder
    expect: str
    #: the bad file's suffix (None: the reader's, see SUFFIXES)
    suffix: str | None = None
    #: the commands to run it through: names, ALL, or None for the reader's CORE commands
    commands: tuple[str, ...] | None = None

    @property
    def file_suffix(self) -> str:
        return self.suffix or SUFFIXES[self.reader]


@dataclass(frozen=True)
class Command:
    """How a command takes a bad file: ``args(bad, good, out)`` -> argv, where ``good`` maps
    a kind ("npz", "bvh", "asf", "amc") to a good input file and ``out`` is the output
    folder (which must not exist afterwards)."""

    name: str
    args: Callable[[Path, dict[str, Path], Path], list]
    needs: tuple[str, ...] = field(default=())


@dataclass(frozen=True)
class Case:
    defect: Defect
    command: Command

    @property
    def id(self) -> str:
        return f"{self.defect.reader}-{self.defect.name}-{self.command.name}"


# --- the commands, per reader --------------------------------------------------------------------

# fmt: off
COMMANDS: dict[str, list[Command]] = {
    # a motion .npz, wherever a command takes one
    "npz": [
        Command("add-noise", lambda b, g, o: ["add-noise", b, "-o", o / "noisy.npz"]),
        Command("denoise", lambda b, g, o: ["denoise", b, "-o", o / "clean.npz"]),
        Command("sample", lambda b, g, o: ["sample", "--from", b, "--frames", 4,
                                           "-o", o / "sample.npz"]),
        Command("export-mesh", lambda b, g, o: ["export-mesh", b, "-o", o / "meshes"]),
        Command("export-bvh", lambda b, g, o: ["export-bvh", b, "-o", o / "take.bvh"]),
        Command("eval-gt", lambda b, g, o: ["eval", "--gt", b, "--pred", g["npz"]], ("npz",)),
        Command("eval-pred", lambda b, g, o: ["eval", "--gt", g["npz"], "--pred", b], ("npz",)),
        Command("view", lambda b, g, o: ["view", b, "-o", o / "page.html"]),
        Command("plot", lambda b, g, o: ["plot", b, "-o", o / "figure.png"]),
    ],
    # a BVH take
    "bvh": [
        Command("import", lambda b, g, o: ["import", b, "-o", o / "take.npz"]),
        Command("denoise", lambda b, g, o: ["denoise", b, "-o", o / "take.bvh"]),
        Command("view", lambda b, g, o: ["view", b, "-o", o / "page.html"]),
        Command("plot", lambda b, g, o: ["plot", b, "-o", o / "figure.png"]),
    ],
    # an AMC take on a good skeleton
    "amc": [
        Command("import", lambda b, g, o: ["import", b, "--asf", g["asf"], "-o", o / "t.npz"],
                ("asf",)),
        Command("denoise", lambda b, g, o: ["denoise", b, "--asf", g["asf"], "-o", o / "t.npz"],
                ("asf",)),
        Command("view", lambda b, g, o: ["view", b, "--asf", g["asf"], "-o", o / "page.html"],
                ("asf",)),
    ],
    # an ASF skeleton under a good AMC take
    "asf": [
        Command("import", lambda b, g, o: ["import", g["amc"], "--asf", b, "-o", o / "t.npz"],
                ("amc",)),
        Command("denoise", lambda b, g, o: ["denoise", g["amc"], "--asf", b, "-o", o / "t.npz"],
                ("amc",)),
        Command("plot", lambda b, g, o: ["plot", g["amc"], "--asf", b, "-o", o / "figure.png"],
                ("amc",)),
    ],
    # a body model, given with --body-model to every command that takes one
    "body": [
        Command("export-mesh", lambda b, g, o: ["export-mesh", g["npz"], "--body-model", b,
                                                "-o", o / "meshes"], ("npz",)),
        Command("import", lambda b, g, o: ["import", g["bvh"], "--body-model", b,
                                           "-o", o / "take.npz"], ("bvh",)),
        Command("export-bvh", lambda b, g, o: ["export-bvh", g["npz"], "--body-model", b,
                                               "-o", o / "take.bvh"], ("npz",)),
        Command("eval", lambda b, g, o: ["eval", "--gt", g["npz"], "--pred", g["npz"],
                                         "--body-model", b], ("npz",)),
        Command("sample", lambda b, g, o: ["sample", "--from", g["npz"], "--frames", 4,
                                           "--body-model", b, "-o", o / "s.npz"], ("npz",)),
        Command("denoise", lambda b, g, o: ["denoise", g["npz"], "--body-model", b,
                                            "-o", o / "clean.npz"], ("npz",)),
        Command("view", lambda b, g, o: ["view", g["npz"], "--body-model", b,
                                         "-o", o / "page.html"], ("npz",)),
        Command("plot", lambda b, g, o: ["plot", g["npz"], "--body-model", b,
                                         "-o", o / "figure.png"], ("npz",)),
    ],
    # a video pipeline's output (pickle, joblib, torch file, .npy)
    "video": [
        Command("import", lambda b, g, o: ["import", b, "-o", o / "take.npz"]),
        Command("denoise", lambda b, g, o: ["denoise", b, "-o", o / "clean.npz"]),
        Command("add-noise", lambda b, g, o: ["add-noise", b, "-o", o / "noisy.npz"]),
        Command("eval-gt", lambda b, g, o: ["eval", "--gt", b, "--pred", g["npz"]], ("npz",)),
        Command("view", lambda b, g, o: ["view", b, "-o", o / "page.html"]),
        Command("plot", lambda b, g, o: ["plot", b, "-o", o / "figure.png"]),
    ],
    # a model checkpoint (.npz of weights and its .json beside it)
    "checkpoint": [
        Command("denoise", lambda b, g, o: ["denoise", g["npz"], "--denoiser", b,
                                            "-o", o / "clean.npz"], ("npz",)),
        Command("sample", lambda b, g, o: ["sample", "--from", g["npz"], "--prior", b,
                                           "-o", o / "s.npz"], ("npz",)),
    ],
}
# fmt: on

#: the reader of each kind of bad file -> its command group (both body-model kinds: "body")
READER_COMMANDS = {"npz": "npz", "bvh": "bvh", "amc": "amc", "asf": "asf", "body-npz": "body",
                   "body-pkl": "body", "checkpoint": "checkpoint", "video-pkl": "video",
                   "video-pt": "video", "video-npy": "video"}  # fmt: skip
SUFFIXES = {"npz": ".npz", "bvh": ".bvh", "amc": ".amc", "asf": ".asf", "body-npz": ".npz",
            "body-pkl": ".pkl", "checkpoint": ".npz", "video-pkl": ".pkl", "video-pt": ".pt",
            "video-npy": ".npy"}  # fmt: skip
#: what every defect of a reader goes through; the rest get the defects marked ``ALL``
CORE = {"npz": ("add-noise", "denoise", "sample"), "bvh": ("import", "denoise"),
        "amc": ("import", "denoise"), "asf": ("import", "denoise"),
        "body": ("export-mesh", "import"), "video": ("import", "denoise")}  # fmt: skip
ALL = ("*",)


# --- npz motion files ----------------------------------------------------------------------------


def _motion(**changes) -> Builder:
    return lambda case: F.npz_bytes(F.motion_members(**changes))


def _members(build: Callable[[dict], object]) -> Builder:
    """A good motion file whose member list ``build(members)`` changes (returns the new list)."""

    def make(case: Path) -> bytes:
        members = F.motion_members()
        return F.npz_bytes(build(members) or members)

    return make


def _truncated(case: Path) -> bytes:
    data = F.good_motion()
    return data[: len(data) // 2]


def _deflate_corrupt(case: Path) -> bytes:
    data = bytearray(F.npz_bytes(F.motion_members(), compress=True))
    start = data.index(b"poses.npy") + len("poses.npy") + 40
    data[start : start + 40] = b"\xff" * 40
    return bytes(data)


def _crc_mismatch(case: Path) -> bytes:
    data = bytearray(F.good_motion())
    start = data.index(b"poses.npy") + 200  # inside the stored array's bytes
    data[start] ^= 0xFF
    return bytes(data)


def _encrypted(case: Path) -> bytes:
    """A good motion file whose members say they are encrypted (general-purpose flag bit 0, in
    the local and the central headers): what a password-protected zip looks like."""
    data = bytearray(F.good_motion())
    for signature, flags in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        at = data.find(signature)
        while at >= 0:
            data[at + flags] |= 0x01
            at = data.find(signature, at + 4)
    return bytes(data)


def _rename(old: str, new: str) -> Callable[[dict], dict]:
    return lambda m: {(new if k == old else k): v for k, v in m.items()}


def _pickle_member(key: str) -> Builder:
    def make(case: Path) -> bytes:
        payload = np.array([F.Payload(case / MARKER)], dtype=object)
        return F.npz_bytes(F.motion_members(**{key: F.npy_bytes(payload)}))

    return make


def _poses(fn) -> Builder:
    """A good file whose poses are ``fn(poses)``."""

    def make(case: Path) -> bytes:
        from tests.conftest import motion_arrays

        poses = motion_arrays(T=F.FRAMES, width=66, num_betas=10)["poses"]
        return F.npz_bytes(F.motion_members(poses=fn(poses)))

    return make


def _with_nan(key: str, value: float, shape: tuple) -> Builder:
    def make(case: Path) -> bytes:
        a = np.zeros(shape)
        a.flat[0] = value
        return F.npz_bytes(F.motion_members(**{key: a}))

    return make


def _all_nan(key: str, value: float, shape: tuple, joint: int | None = None) -> Builder:
    """A file whose ``key`` is ``value`` everywhere (or in every frame of one joint)."""

    def make(case: Path) -> bytes:
        a = np.zeros(shape)
        a[..., slice(None) if joint is None else slice(3 * joint, 3 * joint + 3)] = value
        return F.npz_bytes(F.motion_members(**{key: a}))

    return make


T = F.FRAMES
# fmt: off
NPZ = [
    # the archive
    Defect("npz", "text", lambda c: b"poses,trans\n1,2\n", r"not an \.npz archive", commands=ALL),
    Defect("npz", "empty-file", lambda c: b"", r"empty file, not an \.npz archive"),
    Defect("npz", "truncated", _truncated, r"truncated or corrupt \.npz archive", commands=ALL),
    Defect("npz", "deflate-corrupt", _deflate_corrupt, r"'poses' is corrupt"),
    Defect("npz", "crc-mismatch", _crc_mismatch, r"'poses' is corrupt \(checksum mismatch\)"),
    Defect("npz", "member-not-npy", _members(_rename("poses.npy", "poses")),
           r"member 'poses' is not a numpy array \(\.npy\)", commands=ALL),
    Defect("npz", "member-text", _motion(poses=b"just some text, not an array\n"),
           r"'poses' is not a readable \.npy array"),
    Defect("npz", "duplicate-member",
           lambda c: F.npz_bytes([*F.motion_members().items(), ("poses.npy", np.zeros((T, 66)))]),
           r"holds two members named 'poses\.npy'"),
    Defect("npz", "huge-shape", _motion(poses=F.npy_claiming((10**12, 66))),
           r"'poses' claims shape \(1000000000000, 66\) .* but holds only", commands=ALL),
    Defect("npz", "huge-extra", _motion(camera=F.npy_claiming((2**40,), "<f4")),
           r"'camera' claims shape \(1099511627776,\)"),
    Defect("npz", "short-data", _motion(poses=F.npy_claiming((T, 66), data=b"\0" * 80)),
           r"'poses' claims shape \(8, 66\) .* but holds only 80 bytes"),
    Defect("npz", "bad-header", _motion(poses=b"\x93NUMPY\x01\x00\x10\x00{'descr': nope}\n"),
           r"'poses' is not a readable \.npy array"),
    Defect("npz", "unknown-dtype", _motion(poses=F.npy_claiming((T, 66), descr="<q9")),
           r"'poses' is not a readable \.npy array"),
    Defect("npz", "pickled-poses", _pickle_member("poses"),
           r"'poses' holds pickled Python objects.*--allow-pickle", commands=ALL),
    Defect("npz", "pickled-extra", _pickle_member("meta"), r"'meta' holds pickled Python objects"),
    Defect("npz", "gz-not-gzip", lambda c: F.good_motion(), r"not a readable \.gz file",
           suffix=".npz.gz"),
    Defect("npz", "gz-truncated", lambda c: F.gz(F.good_motion())[:-300],
           r"not a readable \.gz file", suffix=".npz.gz"),
    # the arrays
    Defect("npz", "no-poses", _motion(poses=None), r"no 'poses' array"),
    Defect("npz", "no-members", lambda c: F.npz_bytes({}), r"no 'poses' array.*keys: none"),
    Defect("npz", "poses-width", _motion(poses=np.zeros((T, 50))),
           r"'poses' has shape \(8, 50\), expected \(T, "),
    Defect("npz", "poses-1d", _motion(poses=np.zeros(66)), r"'poses' has shape \(66,\)"),
    Defect("npz", "poses-0d", _motion(poses=np.array(1.0)), r"'poses' has shape \(\)"),
    Defect("npz", "poses-no-frames", _motion(poses=np.zeros((0, 66)), trans=np.zeros((0, 3))),
           r"the motion has no frames"),
    Defect("npz", "poses-complex", _poses(lambda p: p + 1j), r"'poses' holds complex numbers",
           commands=ALL),
    Defect("npz", "poses-text", _motion(poses=np.full((T, 66), "x")), r"'poses' is not numeric"),
    Defect("npz", "poses-structured", _motion(poses=np.zeros(T, dtype=[("a", "<f8", 66)])),
           r"'poses' is not numeric"),
    # NaN / inf are holes (issue 32): refused when nothing is observed to fill them from
    Defect("npz", "poses-nan", _all_nan("poses", np.nan, (T, 66)),
           r"'poses' contains NaN or infinite values in every frame", commands=ALL),
    Defect("npz", "poses-inf", _all_nan("poses", -np.inf, (T, 66)),
           r"'poses' contains NaN or infinite values in every frame"),
    Defect("npz", "poses-joint-nan", _all_nan("poses", np.nan, (T, 66), joint=5),
           r"'poses' contains NaN or infinite values for joint 5 \(right_knee\) in all 8 frames",
           commands=ALL),
    Defect("npz", "poses-huge", _poses(lambda p: p * 1e30),
           r"'poses' holds an angle of .* rad; the file is corrupt", commands=ALL),
    Defect("npz", "poses-float32-max", _poses(lambda p: np.full_like(p, 3e38, np.float32)),
           r"'poses' holds an angle of"),
    Defect("npz", "trans-shape", _motion(trans=np.zeros((T, 2))),
           r"'trans' has shape \(8, 2\), expected \(8, 3\)"),
    Defect("npz", "trans-complex", _motion(trans=np.zeros((T, 3), complex)),
           r"'trans' holds complex numbers"),
    Defect("npz", "trans-nan", _all_nan("trans", np.nan, (T, 3)),
           r"'trans' contains NaN or infinite values in every frame"),
    Defect("npz", "trans-huge", _with_nan("trans", 1e30, (T, 3)),
           r"'trans' reaches 1e\+30 m; the file is corrupt", commands=ALL),
    Defect("npz", "betas-complex", _motion(betas=np.zeros(10, complex)),
           r"'betas' holds complex numbers"),
    Defect("npz", "betas-nan", _with_nan("betas", np.nan, (10,)), r"'betas' contains NaN"),
    Defect("npz", "betas-huge", _with_nan("betas", 1e30, (10,)),
           r"'betas' holds a shape coefficient of 1e\+30", commands=ALL),
    Defect("npz", "betas-text", _motion(betas=np.array(["tall"])), r"'betas' is not numeric"),
    # the frame rate and gender
    Defect("npz", "fps-missing", _motion(mocap_framerate=None), r"no frame rate"),
    Defect("npz", "fps-empty", _motion(mocap_framerate=np.array([])),
           r"'mocap_framerate' is empty; expected one frame rate", commands=ALL),
    Defect("npz", "fps-two", _motion(mocap_framerate=np.array([30.0, 60.0])),
           r"'mocap_framerate' holds 2 values; expected one frame rate"),
    Defect("npz", "fps-complex", _motion(mocap_framerate=np.array(30 + 1j)),
           r"'mocap_framerate' holds complex numbers", commands=ALL),
    Defect("npz", "fps-text", _motion(mocap_framerate=np.array("30")),
           r"'mocap_framerate' is not numeric"),
    Defect("npz", "fps-zero", _motion(mocap_framerate=np.array(0.0)), r"frame rate must be > 0"),
    Defect("npz", "fps-negative", _motion(mocap_framerate=np.array(-30.0)),
           r"frame rate must be > 0"),
    Defect("npz", "fps-nan", _motion(mocap_framerate=np.array(np.nan)),
           r"'mocap_framerate' contains NaN"),
    Defect("npz", "fps-frame-time", _motion(mocap_framerate=np.array(1 / 120)),
           r"frame rate 0\.00833333 Hz is implausible.*a frame time\?"),
    Defect("npz", "fps-huge", _motion(mocap_framerate=np.array(1e12)),
           r"frame rate 1e\+12 Hz is implausible"),
    Defect("npz", "gender-empty", _motion(gender=np.array([], dtype="<U1")), r"'gender' is empty",
           commands=ALL),
    Defect("npz", "gender-two", _motion(gender=np.array(["male", "female"])),
           r"'gender' holds 2 values; expected one"),
    Defect("npz", "gender-number", _motion(gender=np.array(1.5)), r"'gender' is not text"),
    # the joint mask and the split pose arrays
    Defect("npz", "mask-shape", _motion(joint_mask=np.ones((T, 5), bool)),
           r"'joint_mask' has shape \(8, 5\), expected \(8, 22\)"),
    Defect("npz", "mask-text", _motion(joint_mask=np.full((T, 22), "yes")),
           r"'joint_mask' is not true/false values"),
    Defect("npz", "mask-nan", _with_nan("joint_mask", np.nan, (T, 22)),
           r"'joint_mask' contains NaN"),
    Defect("npz", "split-shape",
           _motion(poses=None, root_orient=np.zeros((T, 3)), pose_body=np.zeros((T, 60))),
           r"'pose_body' has shape \(8, 60\), expected \(8, 63\)"),
    Defect("npz", "split-complex",
           _motion(poses=None, root_orient=np.zeros((T, 3)), pose_body=np.zeros((T, 63), complex)),
           r"'pose_body' holds complex numbers"),
    Defect("npz", "split-nan",
           _motion(poses=None, root_orient=np.full((T, 3), np.nan), pose_body=np.zeros((T, 63))),
           r"'root_orient' contains NaN or infinite values for joint 0 \(pelvis\) in all 8"),
    # shapes and types that used to be accepted (issue 33)
    Defect("npz", "betas-3d", _motion(betas=np.zeros((2, 3, 4))),
           r"'betas' has shape \(2, 3, 4\); expected \(S,\), \(1, S\) or one row per frame",
           commands=ALL),
    Defect("npz", "betas-rows", _motion(betas=np.zeros((T + 3, 16))),
           r"'betas' has shape \(11, 16\)"),
    Defect("npz", "poses-timedelta", _motion(poses=np.zeros((T, 66), "timedelta64[s]")),
           r"'poses' is not numeric \(dtype timedelta64\[s\]\)", commands=ALL),
    Defect("npz", "encrypted", _encrypted, r"member 'poses\.npy' is encrypted", commands=ALL),
]
# fmt: on


# --- BVH -----------------------------------------------------------------------------------------


def _bvh(old: str, new: str, count: int = 1) -> Builder:
    """The good take with its first ``count`` occurrences of ``old`` replaced by ``new``."""

    def make(case: Path) -> bytes:
        text = F.bvh_text()
        assert old in text, old
        return text.replace(old, new, count).encode()

    return make


_ROW0 = "0.0000 95.0000 0.0000"  # the first frame's root position
# fmt: off
BVH = [
    Defect("bvh", "not-bvh", lambda c: b"just a text file\n", r"not a BVH file", commands=ALL),
    Defect("bvh", "empty-file", lambda c: b"", r"not a BVH file"),
    Defect("bvh", "binary", lambda c: b"HIERARCHY\0\0\x01\x02", r"binary data, not a text"),
    Defect("bvh", "no-motion", lambda c: F.bvh_hierarchy()[0].encode(), r"no MOTION section"),
    Defect("bvh", "no-root", _bvh("ROOT Hips", "JOINT Hips"), r"expected 'ROOT', got 'JOINT'"),
    Defect("bvh", "unclosed", _bvh("}\nMOTION", "MOTION"),
           r"unexpected end of the hierarchy \(expected '\}' closing Hips\)"),
    Defect("bvh", "offset-text", _bvh("OFFSET 0 10 0", "OFFSET 0 ten 0"),
           r"expected a number for the OFFSET of Spine, got 'ten'"),
    Defect("bvh", "offset-nan", _bvh("OFFSET 0 10 0", "OFFSET 0 nan 0"),
           r"the OFFSET of Spine is not finite", commands=ALL),
    Defect("bvh", "offset-inf", _bvh("OFFSET 0 10 0", "OFFSET 0 inf 0"),
           r"the OFFSET of Spine is not finite"),
    Defect("bvh", "channels-seven", _bvh("CHANNELS 3", "CHANNELS 7"),
           r"joint Spine has a bad channel count 7"),
    Defect("bvh", "channels-nan", _bvh("CHANNELS 3", "CHANNELS nan"),
           r"joint Spine has a bad channel count nan", commands=ALL),
    Defect("bvh", "channels-inf", _bvh("CHANNELS 3", "CHANNELS inf"),
           r"joint Spine has a bad channel count inf"),
    Defect("bvh", "channel-unknown", _bvh("Zrotation", "Wrotation"),
           r"joint Hips has an unknown channel 'Wrotation'"),
    Defect("bvh", "duplicate-joint", _bvh("JOINT Spine1", "JOINT Spine"),
           r"joint name 'Spine' appears twice"),
    Defect("bvh", "end-site-content", _bvh("OFFSET 0 5 0\n", "OFFSET 0 5 0\n JOINT X\n"),
           r"End Site of Head has extra content"),
    Defect("bvh", "after-root", _bvh("}\nMOTION", "}\nJOINT Extra\nMOTION"),
           r"unexpected 'JOINT' after the root joint"),
    Defect("bvh", "no-frames-line", _bvh("Frames: 8\n", ""),
           r"MOTION section lacks its 'Frames:' line \(before 'Frame Time:'\)"),
    Defect("bvh", "frames-text", _bvh("Frames: 8", "Frames: eight"),
           r"bad 'Frames:' or 'Frame Time:' value"),
    Defect("bvh", "frame-time-zero", _bvh("Frame Time: 0.0333333", "Frame Time: 0"),
           r"Frame Time must be > 0"),
    Defect("bvh", "frame-time-nan", _bvh("Frame Time: 0.0333333", "Frame Time: nan"),
           r"Frame Time must be > 0"),
    Defect("bvh", "frame-time-rate", _bvh("Frame Time: 0.0333333", "Frame Time: 120"),
           r"frame rate 0\.00833333 Hz is implausible.*Frame Time a frame rate\?"),
    Defect("bvh", "frames-zero", lambda c: F.bvh_text(rows=[]).encode(), r"no motion frames"),
    Defect("bvh", "data-text", _bvh(_ROW0, "0.0000 abc 0.0000"),
           r"non-numeric value in the motion data"),
    Defect("bvh", "data-short", lambda c: F.bvh_text().rsplit(" ", 1)[0].encode(),
           r"motion data has \d+ values, not a multiple of the 66 channels"),
    Defect("bvh", "frames-mismatch", _bvh("Frames: 8", "Frames: 9"),
           r"header says 9 frames but the file holds 8"),
    Defect("bvh", "data-nan", _bvh(_ROW0, "nan 95.0000 0.0000"),
           r"motion data holds NaN or infinite values \(first at frame 1, Hips Xposition\)",
           commands=ALL),
    Defect("bvh", "data-inf", _bvh(_ROW0, "0.0000 -inf 0.0000"),
           r"motion data holds NaN or infinite values \(first at frame 1, Hips Yposition\)"),
    Defect("bvh", "angle-huge", _bvh(_ROW0 + " 0.0000", _ROW0 + " 1e30"),
           r"joint Hips holds an angle of 1e\+30 degrees; the file is corrupt"),
    Defect("bvh", "position-huge", _bvh(_ROW0, "0.0000 1e30 0.0000"),
           r"the root position reaches .* m; the file is corrupt"),
    Defect("bvh", "all-blank", lambda c: F.bvh_text(rows=["0 " * 66] * 3).encode(),
           r"every frame is blank"),
    Defect("bvh", "no-channels",
           _bvh(
            "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation", "CHANNELS 0"
        ),
           r"not a multiple of the 60 channels"),
    Defect("bvh", "deep-hierarchy", lambda c: F.deep_bvh(10_000).encode(),
           r"the joint hierarchy is more than 1000 joints deep", commands=ALL),
    Defect("bvh", "not-humanoid",
           lambda c: F.bvh_text().replace("Left", "Port").replace("Right", "Star").encode(),
           r"cannot map the skeleton onto SMPL: no joint found for left_hip"),
    Defect("bvh", "gz-not-gzip", lambda c: F.bvh_text().encode(), r"not a readable \.gz file",
           suffix=".bvh.gz"),
    Defect("bvh", "gz-truncated", lambda c: F.gz(F.bvh_text())[:-40], r"not a readable \.gz",
           suffix=".bvh.gz"),
]
# fmt: on


# --- ASF/AMC -------------------------------------------------------------------------------------


def _asf(old: str, new: str) -> Builder:
    def make(case: Path) -> bytes:
        text = F.asf_text()
        assert old in text, old
        return text.replace(old, new, 1).encode()

    return make


def _amc(old: str, new: str) -> Builder:
    def make(case: Path) -> bytes:
        text = F.amc_text(frames=32)
        assert old in text, old
        return text.replace(old, new, 1).encode()

    return make


# fmt: off
ASF = [
    Defect("asf", "not-asf", lambda c: b"hello\n", r"not an ASF skeleton \(no :root section\)",
           suffix=".asf", commands=ALL),
    Defect("asf", "empty-file", lambda c: b"", r"not an ASF skeleton"),
    Defect("asf", "binary", lambda c: b":root\0\0", r"binary data, not a text"),
    Defect("asf", "no-direction", _asf("     direction 0 -1 0\n", ""),
           r"bone lfemur has no direction"),
    Defect("asf", "length-text", _asf("length 7", "length seven"),
           r"expected numbers for the length of lfemur, got 'seven'"),
    Defect("asf", "length-negative", _asf("length 7", "length -7"),
           r"bone lfemur has a negative length"),
    Defect("asf", "length-nan", _asf("length 7", "length nan"),
           r"the length of lfemur is not finite", commands=ALL),
    Defect("asf", "length-huge", _asf("length 7", "length 1e30"),
           r"bone lfemur is .* m long; the file is corrupt"),
    Defect("asf", "axis-order", _asf("axis 0 0 0 XYZ", "axis 0 0 0 XXZ"), r"bad axis order 'XXZ'"),
    Defect("asf", "unknown-dof", _asf("dof rx ry rz", "dof rx ry spin"),
           r"bone lfemur has an unknown dof 'spin'"),
    Defect("asf", "unknown-child", _asf("lhipjoint rhipjoint", "lhipjoint ghost"),
           r"hierarchy names an unknown bone 'ghost'"),
    Defect("asf", "two-parents", _asf("lfemur ltibia", "lfemur ltibia lhumerus"),
           r"bone 'lhumerus' has two parents|bone 'ltibia' has two parents"),
    Defect("asf", "units-zero", _asf("length 0.45", "length 0"), r":units length must be > 0"),
    Defect("asf", "duplicate-bone", _asf("name rfemur", "name lfemur"),
           r"bone 'lfemur' defined twice"),
    Defect("asf", "unterminated",
           lambda c: (
            F.asf_text().split(":hierarchy")[0].rsplit("  end", 1)[0].encode()
            + b":hierarchy\n begin\n root lfemur\n end\n"
        ),
           r"unterminated bone block"),
]
# fmt: on

# fmt: off
AMC = [
    Defect("amc", "empty-file", lambda c: b"", r"no motion frames in the AMC file", commands=ALL),
    Defect("amc", "is-asf", lambda c: F.asf_text().encode(),
           r"this is an ASF skeleton, not an AMC motion"),
    Defect("amc", "binary", lambda c: b"1\0\0root", r"binary data, not a text"),
    Defect("amc", "no-frame-number", _amc("\n1\n", "\n"),
           r"AMC data must start with a frame number"),
    Defect("amc", "unknown-bone", _amc("lfemur", "ghost"),
           r"AMC names bone 'ghost', which the skeleton lacks"),
    Defect("amc", "value-count", _amc("\nltibia ", "\nltibia 1 "),
           r"AMC frame 1: bone ltibia has 2 values, the skeleton gives it 1"),
    Defect("amc", "value-text", _amc("root 0 17 0 0 0 0", "root 0 17 abc 0 0 0"),
           r"non-numeric AMC value in frame 1"),
    Defect("amc", "value-nan", _amc("root 0 17 0 0 0 0", "root 0 17 nan 0 0 0"),
           r"bone root has NaN or infinite values", commands=ALL),
    Defect("amc", "angle-huge", _amc("root 0 17 0 0 0 0", "root 0 17 0 1e30 0 0"),
           r"the root holds an angle of 1e\+30 degrees"),
    Defect("amc", "position-huge", _amc("root 0 17 0 0 0 0", "root 1e30 17 0 0 0 0"),
           r"the root position reaches .* m; the file is corrupt"),
    Defect("amc", "no-bone-lines",
           lambda c: b":FULLY-SPECIFIED\n:DEGREES\n1\n2\n3\n4\n5\n6\n7\n8\n",
           r"frame numbers but no bone lines", commands=ALL),
    Defect("amc", "gz-not-gzip", lambda c: F.amc_text(frames=32).encode(),
           r"not a readable \.gz file", suffix=".amc.gz"),
]
# fmt: on


# --- body models ---------------------------------------------------------------------------------


def _body_npz(**changes) -> Builder:
    return lambda case: F.npz_bytes(F.body_members(**changes))


def _body_pkl(**changes) -> Builder:
    return lambda case: F.body_pickle(**changes)


def _payload_pkl(via: str, where: str) -> Builder:
    """A body-model pickle holding a payload: as the whole file, or as one array's value."""

    def make(case: Path) -> bytes:
        payload = F.Payload(case / MARKER, via)
        return F.pickled(payload) if where == "file" else F.body_pickle(weights=payload)

    return make


def _body_pickled_member(case: Path) -> bytes:
    payload = np.array([F.Payload(case / MARKER)], dtype=object)
    return F.npz_bytes(F.body_members(weights=F.npy_bytes(payload)))


def _sparse(**state) -> object:
    """A pickled scipy.sparse csc matrix stand-in with ``state`` (no scipy needed to write it)."""
    return F.ForeignObject("scipy.sparse._csc", "csc_matrix", state)


# fmt: off
BODY = [
    Defect("body-npz", "text", lambda c: b"not a body\n", r"body model bad\.npz: not an npz",
           commands=ALL),
    Defect("body-npz", "truncated", lambda c: F.npz_bytes(F.body_members())[:3000],
           r"body model bad\.npz: truncated or corrupt \.npz archive"),
    Defect("body-npz", "missing-key", _body_npz(weights=None), r"missing 'weights'"),
    Defect("body-npz", "kintree-shape", _body_npz(kintree_table=np.zeros((3, 24), int)),
           r"'kintree_table' must be \(2, J\)"),
    Defect("body-npz", "joints-30",
           _body_npz(kintree_table=np.stack([np.arange(30) - 1, np.arange(30)])),
           r"kinematic tree has 30 joints"),
    Defect("body-npz", "template-shape", _body_npz(v_template=np.zeros((192, 2))),
           r"'v_template' must be \(V, 3\)"),
    Defect("body-npz", "template-nan", _body_npz(v_template=np.full((192, 3), np.nan)),
           r"'v_template' holds NaN or infinite values", commands=ALL),
    Defect("body-npz", "template-complex", _body_npz(v_template=np.zeros((192, 3), complex)),
           r"'v_template' is not a numeric array"),
    Defect("body-npz", "regressor-shape", _body_npz(J_regressor=np.zeros((24, 10))),
           r"'J_regressor' must be \(24, 192\)"),
    Defect("body-npz", "faces-range", _body_npz(f=np.full((10, 3), 999)),
           r"'f' \(faces\) indexes vertices outside"),
    Defect("body-npz", "pickled-member", _body_pickled_member,
           r"'weights': refusing to load 'posix.system'", commands=ALL),
    Defect("body-npz", "huge-shape", _body_npz(v_template=F.npy_claiming((10**12, 3))),
           r"'v_template' claims shape \(1000000000000, 3\)", commands=ALL),
    Defect("body-npz", "member-not-npy",
           lambda c: F.npz_bytes(
            {("weights" if k == "weights.npy" else k): v for k, v in F.body_members().items()}
        ),
           r"member 'weights' is not a numpy array"),
    Defect("body-npz", "unsupported-suffix", lambda c: F.npz_bytes(F.body_members()),
           r"unsupported file type '\.txt'", suffix=".txt"),
    Defect("body-pkl", "not-pickle", lambda c: b"not a pickle\n",
           r"body model bad\.pkl: not a readable body-model pickle"),
    Defect("body-pkl", "truncated", lambda c: F.body_pickle()[:5000],
           r"not a readable body-model pickle \(it is truncated\)"),
    Defect("body-pkl", "a-list", lambda c: F.pickled([1, 2, 3]),
           r"pickle holds a list, expected a dict"),
    Defect("body-pkl", "payload-system", _payload_pkl("system", "file"),
           r"refusing to load 'posix\.system' from the pickle", commands=ALL),
    Defect("body-pkl", "payload-open", _payload_pkl("open", "value"),
           r"refusing to load '.*open' from the pickle", commands=ALL),
    Defect("body-pkl", "huge-array", lambda c: F.body_pickle(weights=F.HugeArray()),
           r"body model bad\.pkl: .*too large"),
    Defect("body-pkl", "sparse-range",
           lambda c: F.body_pickle(
            J_regressor=_sparse(
                _shape=(24, 192),
                data=np.ones(1),
                indices=np.array([500]),
                indptr=np.r_[0, np.ones(192, int)],
            )
        ),
           r"cannot rebuild 'J_regressor' \(sparse indices out of range\)"),
    Defect("body-pkl", "template-nan", _body_pkl(v_template=np.full((192, 3), np.nan)),
           r"'v_template' holds NaN or infinite values"),
    # a 1 MB pickle whose posedirs are one 0.9 MB array referred to 4,000 times (took 10 GB)
    Defect("body-pkl", "repeated-array",
           lambda c: F.body_pickle(posedirs=[np.zeros((1000, 216), np.float32)] * 4000),
           r"body model bad\.pkl: its arrays add up to 3\.22 GiB once the parts it repeats are "
           r"expanded"),
    Defect("body-pkl", "sparse-huge",
           lambda c: F.body_pickle(
            J_regressor=_sparse(_shape=(10**12, 192), data=np.ones(1), indices=np.array([5]),
                                indptr=np.r_[0, np.ones(192, int)])
        ),
           r"body model bad\.pkl: its arrays add up to 1\.43e\+06 GiB"),
]
# fmt: on


# --- checkpoints ---------------------------------------------------------------------------------

# fmt: off
CHECKPOINT = [
    Defect("checkpoint", "no-json", lambda c: F.npz_bytes({"a.npy": np.zeros(3)}),
           r"is not an mdvae checkpoint: its metadata bad\.json is not beside it", commands=ALL),
    Defect("checkpoint", "not-npz", lambda c: F.checkpoint_with(c, b"weights?", "{}"),
           r"not an \.npz archive", commands=ALL),
    Defect("checkpoint", "bad-json", lambda c: F.checkpoint_with(c, None, "{not json"),
           r"metadata bad\.json is not valid JSON", commands=ALL),
    Defect("checkpoint", "no-config", lambda c: F.checkpoint_with(c, None, "{}"),
           r"is not a .* checkpoint", commands=ALL),
    Defect("checkpoint", "prior-as-denoiser", lambda c: F.checkpoint_with(c, None, None, "prior"),
           r"is not a denoiser checkpoint", commands=("denoise",)),
    Defect("checkpoint", "pickled",
           lambda c: F.checkpoint_with(
            c, F.npz_bytes({"w.npy": F.npy_bytes(np.array([F.Payload(c / MARKER)], object))}), None
        ),
           r"'w' holds pickled Python objects", commands=ALL),
    Defect("checkpoint", "denoiser-weights", lambda c: F.checkpoint_with(c, None, None, drop=3),
           r"weights do not match its config: 3 missing", commands=("denoise",)),
    Defect("checkpoint", "weights-inf",
           lambda c: F.checkpoint_with(c, None, None, change=lambda a: np.full_like(a, np.inf)),
           r"weight '.*' holds NaN or infinite values; the checkpoint is damaged",
           commands=("denoise",)),
    Defect("checkpoint", "weights-complex",
           lambda c: F.checkpoint_with(c, None, None, "prior", change=lambda a: a + 1j),
           r"weight '.*' is torch\.complex\d+, not real numbers", commands=("sample",)),
    Defect("checkpoint", "a-motion", lambda c: F.checkpoint_with(c, F.good_motion(), None),
           r"checkpoint .*bad\.npz: 'gender' holds text, not weights \(is it a checkpoint\?\)",
           commands=ALL),
    Defect("checkpoint", "prior-weights",
           lambda c: F.checkpoint_with(c, None, None, "prior", drop=3),
           r"weights do not match its config: 3 missing", commands=("sample",)),
]
# fmt: on


# --- video pipelines' outputs -------------------------------------------------------------------


def _hybrik(**changes) -> Builder:
    """HybrIK's res.pk (a plain pickle) of a small clip, with ``changes`` to its keys."""
    return lambda c: F.pickled({**F.hybrik_result(), **changes}, protocol=4)


def _wham_cut(n: int) -> Builder:
    """The first ``n`` bytes of a WHAM output (a joblib stream): a truncated file."""
    return lambda c: F.wham_bytes()[:n]


def _wham_ids(ids: np.ndarray) -> Builder:
    """A WHAM output of 12 frames whose ``frame_ids`` are ``ids``."""

    def make(case: Path) -> bytes:
        from tests import video_files

        path = case / "wham.tmp"
        video_files.write_wham(path, {0: (video_files.clip(12, seed=6), ids)})
        data = path.read_bytes()
        path.unlink()
        return data

    return make


def _gvhmr_expanded(case: Path) -> bytes:
    """A GVHMR output whose tensors show one stored zero as 4 million frames each."""
    import torch

    def z(*shape):
        return torch.zeros(1).expand(4_000_000, *shape)

    params = {"body_pose": z(63), "betas": z(10), "global_orient": z(3), "transl": z(3)}
    return F.torch_bytes({"smpl_params_global": params, "smpl_params_incam": dict(params)})


_REFUSED = r"refusing to load '.*' from the pickle .*nothing was run"
_LAYOUT = r"not a motion layout this tool knows \(if it is one of .*read it with --format"

# fmt: off
VIDEO = [
    Defect("video-pkl", "not-pickle", lambda c: b"not a pickle at all\n",
           r"bad\.pkl: not a pickle, joblib, torch or \.npy file", commands=ALL),
    Defect("video-pkl", "empty", lambda c: b"", r"bad\.pkl: the file is empty"),
    Defect("video-pkl", "truncated", _wham_cut(300), r"bad\.pkl: the file is truncated"),
    Defect("video-pkl", "truncated-early", _wham_cut(40), r"bad\.pkl: the file is truncated"),
    Defect("video-pkl", "payload-system", lambda c: F.pickled({"0": F.Payload(c / MARKER)}),
           _REFUSED, commands=ALL),
    Defect("video-pkl", "payload-open",
           lambda c: F.pickled({"pose": F.Payload(c / MARKER, "open")}), _REFUSED),
    Defect("video-pkl", "unknown-layout", lambda c: F.pickled({"a": np.zeros(2)}), _LAYOUT),
    Defect("video-pkl", "a-list", lambda c: F.pickled([1, 2, 3]), _LAYOUT),
    Defect("video-pkl", "huge-array", _hybrik(pred_thetas=F.HugeArray()),
           r"bad\.pkl: an array in it is too large to load"),
    Defect("video-pkl", "pose-nan", _hybrik(pred_thetas=np.full((12, 216), np.nan, np.float32)),
           r"'pred_thetas' holds NaN or infinite values", commands=ALL),
    Defect("video-pkl", "pose-inf", _hybrik(pred_thetas=np.full((12, 216), np.inf, np.float32)),
           r"'pred_thetas' holds NaN or infinite values"),
    Defect("video-pkl", "pose-shape", _hybrik(pred_thetas=np.zeros((12, 215), np.float32)),
           r"'pred_thetas' has shape \(12, 215\), expected \(T, 216\)"),
    Defect("video-pkl", "no-frames", _hybrik(pred_thetas=np.zeros((0, 216), np.float32)),
           r"'pred_thetas' has no frames"),
    Defect("video-pkl", "pose-text", _hybrik(pred_thetas=np.array(["abc"])),
           r"'pred_thetas' is not numeric"),
    Defect("video-pkl", "pose-complex",
           _hybrik(pred_thetas=np.zeros((12, 216), np.complex64)),
           r"'pred_thetas' holds complex numbers", commands=ALL),
    Defect("video-pt", "payload", lambda c: F.torch_bytes({"smpl_params_global":
                                                           F.Payload(c / MARKER)}),
           _REFUSED, commands=ALL),
    Defect("video-pt", "damaged-zip", lambda c: b"PK\x03\x04" + b"\x00" * 40,
           r"bad\.pt: the file is truncated or damaged"),
    Defect("video-pt", "unknown-layout", lambda c: F.torch_bytes({"foo": np.zeros(3)}), _LAYOUT),
    Defect("video-npy", "payload",
           lambda c: F.npy_bytes(np.array([F.Payload(c / MARKER)], object)), _REFUSED,
           commands=ALL),
    Defect("video-npy", "plain-array", lambda c: F.npy_bytes(np.zeros((4, 3))), _LAYOUT),
    # issue 33: invalid data that used to be accepted, limits that must hold while reading,
    # and formats mdvae does not read, named with the way forward
    Defect("video-pkl", "zero-matrices", _hybrik(pred_thetas=np.zeros((12, 216), np.float32)),
           r"'pred_thetas' holds matrices that are not rotations \(determinant 0", commands=ALL),
    Defect("video-pkl", "frame-ids-jump", _wham_ids(np.array([0, *range(2, 12), 10**9])),
           r"frame ids 0\.\.1000000000 for 12 frames", commands=ALL),
    Defect("video-pkl", "frame-ids-nan", _wham_ids(np.full(12, np.nan)),
           r"frame ids that are NaN, infinite or not whole numbers"),
    Defect("video-pkl", "frame-ids-repeated", _wham_ids(np.zeros(12, np.int64)),
           r"12 frames but only 1 distinct frame ids"),
    Defect("video-pkl", "empty-fbx", lambda c: b"", r"bad\.fbx: FBX is not supported: export the "
           r"take as BVH", suffix=".fbx", commands=ALL),
    Defect("video-pkl", "c3d", lambda c: b"\x02\x50" + b"\0" * 510,
           r"bad\.c3d: C3D marker files are not supported", suffix=".c3d", commands=ALL),
    Defect("video-pkl", "a-video", lambda c: b"\0\0\0\x18ftypmp42",
           r"bad\.mp4: a video, not a motion file: run a video pose pipeline", suffix=".mp4"),
    # small files that would expand to gigabytes: one 0.9 MB array referred to 4,000 times,
    # and tensors of a 4-byte storage each claiming 4 million frames (strides of 0)
    Defect("video-pkl", "repeated-array",
           _hybrik(pred_thetas=[np.zeros((1000, 216), np.float32)] * 4000),
           r"bad\.pkl: its arrays add up to 3\.22 GiB \(over 512 MiB\) once the parts it "
           r"repeats are expanded", commands=ALL),
    Defect("video-pt", "stride-zero", _gvhmr_expanded,
           r"bad\.pt: its arrays add up to over 512 MiB once the parts it repeats are expanded",
           commands=ALL),
]
# fmt: on


# --- the table -----------------------------------------------------------------------------------

DEFECTS = [*NPZ, *BVH, *ASF, *AMC, *BODY, *CHECKPOINT, *VIDEO]


def cases() -> list[Case]:
    """Every defect through the commands that read it: its reader's core commands (all of
    them when the reader has no core list), or every command for defects marked ALL."""
    out = []
    for defect in DEFECTS:
        group = READER_COMMANDS[defect.reader]
        commands = COMMANDS[group]
        core = CORE.get(group)
        for command in commands:
            if defect.commands not in (None, ALL):
                chosen = command.name in defect.commands
            else:
                chosen = defect.commands == ALL or core is None or command.name in core
            if chosen:
                out.append(Case(defect, command))
    return out

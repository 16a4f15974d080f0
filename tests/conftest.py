"""Shared test fixtures: small synthetic motion files and a tiny body model.

* ``motion_arrays(T, width, fps, seed)`` — the arrays of a smooth AMASS-style clip (plain function).
* ``make_motion_file`` fixture — writes such a clip as an .npz under ``tmp_path``; any array can be
  replaced or removed (``None``) through keyword arguments, e.g. ``poses=None`` or
  ``mocap_framerate=0``.
* ``hash_tree`` fixture — ``hash_tree(folder)`` gives {relative path: SHA-256} of every file, to
  check that inputs are left untouched.
* ``tiny_body`` fixture — a valid 24-joint :class:`BodyModelData` with a few hundred vertices,
  for fast skinning, metric and export tests that do not need a realistic mesh.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from mdvae_cli.body.data import SMPL_JOINT_NAMES, SMPL_PARENTS, BodyModelData

_UNSET = object()


def motion_arrays(
    T: int = 60, width: int = 156, fps: float = 30.0, seed: int = 0, num_betas: int = 16
) -> dict[str, np.ndarray]:
    """A smooth, plausible-looking clip in AMASS layout (all joints swing sinusoidally).

    poses (T, width) axis-angles of amplitude <= 0.4 rad, trans (T, 3) a slow walk along x at
    pelvis height ~0.9 m (z-up), betas (num_betas,), mocap_framerate, gender "neutral".
    """
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None] / fps
    freq = rng.uniform(0.3, 1.5, size=(1, width))
    phase = rng.uniform(0, 2 * np.pi, size=(1, width))
    amp = rng.uniform(0.05, 0.4, size=(1, width))
    poses = amp * np.sin(2 * np.pi * freq * t + phase)
    trans = np.concatenate([0.8 * t, 0.05 * np.sin(2 * np.pi * t), 0.9 + 0.02 * np.cos(4 * t)], 1)
    return {
        "poses": poses,
        "trans": trans,
        "betas": rng.normal(0, 0.5, size=num_betas),
        "mocap_framerate": np.array(float(fps)),
        "gender": np.array("neutral"),
    }


@pytest.fixture
def make_motion_file(tmp_path: Path):
    """Factory: ``make_motion_file(name="motion.npz", T=60, width=156, fps=30.0, **arrays)``.

    ``name`` may hold sub-folders (created); keyword arrays replace the generated ones, and an
    array given as None is left out of the file. Returns the written path.
    """

    def make(
        name: str | Path = "motion.npz",
        T: int = 60,
        width: int = 156,
        fps: float = 30.0,
        seed: int = 0,
        num_betas: int = 16,
        **arrays,
    ) -> Path:
        data = motion_arrays(T=T, width=width, fps=fps, seed=seed, num_betas=num_betas)
        for key, value in arrays.items():
            if value is None:
                data.pop(key, None)
            else:
                data[key] = np.asarray(value)
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as fh:
            np.savez(fh, **data)
        return path

    return make


def run_cli(*args) -> tuple[int, str, str]:
    """``mdvae ARGS`` in-process -> (exit code, stdout, stderr); an escaped exception fails."""
    from click.testing import CliRunner

    from mdvae_cli.cli.main import cli

    result = CliRunner().invoke(cli, [str(a) for a in args])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def one_error_line(code: int, out: str, err: str) -> str:
    """The one ``error:`` line of a refusal (exit 1, no traceback, nothing else)."""
    lines = [ln for ln in (out + err).splitlines() if ln.strip()]
    assert code == 1 and len(lines) == 1 and lines[0].startswith("error: "), lines
    assert "Traceback" not in out + err
    return lines[0]


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (to check inputs are left untouched)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def tree_digest(root: Path) -> dict[str, str]:
    """{relative path: SHA-256} for every file below ``root``."""
    return {p.relative_to(root).as_posix(): file_digest(p) for p in root.rglob("*") if p.is_file()}


def make_tiny_body(verts_per_joint: int = 8, num_betas: int = 10, seed: int = 0) -> BodyModelData:
    """A 24-joint SMPL-shaped body with ``24 * verts_per_joint`` vertices.

    Joints sit on a rough standing skeleton; each owns a ring of vertices around it, rigidly
    skinned (weight 1 to its joint); the joint regressor averages a joint's own ring, so the
    rest joints are exactly the ring centres. No pose correctives; small random shape directions.
    """
    rng = np.random.default_rng(seed)
    J = len(SMPL_PARENTS)
    offsets = rng.normal(0, 0.12, size=(J, 3))
    offsets[:, 2] -= 0.05  # roughly hanging downwards (z-up)
    joints = np.zeros((J, 3))
    joints[0] = (0.0, 0.0, 0.9)
    for j in range(1, J):
        joints[j] = joints[SMPL_PARENTS[j]] + offsets[j]
    angles = np.linspace(0, 2 * np.pi, verts_per_joint, endpoint=False)
    ring = 0.04 * np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    ring -= ring.mean(axis=0)
    v_template = (joints[:, None, :] + ring[None]).reshape(-1, 3)
    V = v_template.shape[0]
    owner = np.repeat(np.arange(J), verts_per_joint)
    weights = np.zeros((V, J))
    weights[np.arange(V), owner] = 1.0
    J_regressor = weights.T / verts_per_joint
    faces = []
    for j in range(J):
        base = j * verts_per_joint
        for k in range(1, verts_per_joint - 1):
            faces.append((base, base + k, base + k + 1))
    return BodyModelData(
        kind="smpl",
        v_template=v_template,
        shapedirs=rng.normal(0, 0.005, size=(V, 3, num_betas)),
        posedirs=np.zeros((V, 3, 9 * (J - 1))),
        J_regressor=J_regressor,
        weights=weights,
        parents=np.asarray(SMPL_PARENTS, dtype=np.int64),
        faces=np.asarray(faces, dtype=np.int64),
        joint_names=SMPL_JOINT_NAMES,
        marker_vertex_ids=np.arange(0, V, max(V // 43, 1))[:43].astype(np.int64),
        name="tiny-test-body",
    ).validate()


@pytest.fixture
def hash_tree():
    """The :func:`tree_digest` function (``hash_tree(folder)`` -> {relative path: SHA-256})."""
    return tree_digest


@pytest.fixture(scope="session")
def tiny_body() -> BodyModelData:
    """See :func:`make_tiny_body`."""
    return make_tiny_body()

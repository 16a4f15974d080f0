"""ASF/AMC in, AMC out: takes written back on their own skeleton (issue 20)."""

from __future__ import annotations

import gzip
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.cli.main import cli
from mdvae_cli.errors import InputError
from mdvae_cli.formats.amc_write import amc_text, format_value
from mdvae_cli.formats.asf import load_asf
from mdvae_cli.formats.asfamc import load_amc
from mdvae_cli.motion.motion import Motion
from mdvae_cli.retarget.dof_solve import chain_rotation, closest_angles
from mdvae_cli.retarget.fit_shape import BodyJoints
from mdvae_cli.retarget.retarget import load_source
from mdvae_cli.retarget.take import read_take, write_take
from mdvae_cli.retarget.way_back import smpl_globals
from mdvae_cli.retarget.way_back_amc import amc_pose, write_back_amc

REPO = Path(__file__).resolve().parents[1]
CMU = REPO.parent / "shared" / "data" / "cmu"
needs_cmu = pytest.mark.skipif(not (CMU / "asfamc").is_dir(), reason=f"no CMU data at {CMU}")

# a CMU-style rig (y up, facing +z, left = +x), made up here: name, parent, direction, length
# (units of 0.45 inch), axis (degrees, XYZ), dofs
_LEFT = [
    ("lhipjoint", "root", (0.55, -0.75, 0.35), 2.3, (0, 0, 0), ""),
    ("lfemur", "lhipjoint", (0.3, -0.95, 0), 7.2, (0, 0, 18), "rx ry rz"),
    ("ltibia", "lfemur", (0.3, -0.95, 0), 7.3, (0, 0, 18), "rx"),
    ("lfoot", "ltibia", (0.07, -0.2, 0.98), 2.3, (-90, 0, 18), "rx rz"),
    ("ltoes", "lfoot", (0, 0, 1), 1.1, (-90, 0, 18), "rx"),
    ("lclavicle", "thorax", (0.92, 0.35, -0.1), 3.4, (0, 0, 0), "ry rz"),
    ("lhumerus", "lclavicle", (1, 0, 0), 5.0, (180, -30, -90), "rx ry rz"),
    ("lradius", "lhumerus", (1, 0, 0), 3.5, (180, -30, -90), "rx"),
    ("lwrist", "lradius", (1, 0, 0), 1.7, (0, 90, 90), "ry"),
    ("lhand", "lwrist", (1, 0, 0), 0.7, (0, 90, 90), "rx rz"),
    ("lfingers", "lhand", (1, 0, 0), 0.6, (0, 90, 90), "rx"),
    ("lthumb", "lwrist", (0.7, 0, 0.7), 0.8, (-90, 45, 0), "rx rz"),
]
_SPINE = [
    ("lowerback", "root", (0, 1, -0.05), 2.0, (0, 0, 0), "rx ry rz"),
    ("upperback", "lowerback", (0, 1, 0), 2.0, (0, 0, 0), "rx ry rz"),
    ("thorax", "upperback", (0, 1, 0.02), 2.0, (0, 0, 0), "rx ry rz"),
    ("lowerneck", "thorax", (0, 1, 0.1), 1.7, (0, 0, 0), "rx ry rz"),
    ("upperneck", "lowerneck", (0, 1, -0.05), 1.7, (0, 0, 0), "rx ry rz"),
    ("head", "upperneck", (0, 1, 0), 1.7, (0, 0, 0), "rx ry rz"),
]


def _right(bone):
    """The right side's bone: names l* -> r*, mirrored across x (axis angles a, -b, -c)."""
    name, parent, d, length, a, dofs = bone
    parent = "r" + parent[1:] if parent.startswith("l") else parent
    return "r" + name[1:], parent, (-d[0], d[1], d[2]), length, (a[0], -a[1], -a[2]), dofs


RIG = _SPINE + _LEFT + [_right(b) for b in _LEFT]


def asf_text(unit: str = "deg") -> str:
    rad = unit == "rad"
    lines = [":version 1.10", ":name generated", ":units", "  mass 1.0", "  length 0.45",
             f"  angle {unit}", ":root", "   order TX TY TZ RX RY RZ", "   axis XYZ",
             "   position 0 0 0", "   orientation 0 0 0", ":bonedata"]  # fmt: skip
    for i, (name, _, d, length, a, dofs) in enumerate(RIG, start=1):
        axis = " ".join(f"{math.radians(v) if rad else v:.9g}" for v in a)
        lines += ["  begin", f"     id {i}", f"     name {name}",
                  f"     direction {d[0]} {d[1]} {d[2]}", f"     length {length}",
                  f"     axis {axis} XYZ"]  # fmt: skip
        if dofs:
            lines.append(f"    dof {dofs}")
        lines.append("  end")
    lines += [":hierarchy", "  begin"]
    kids: dict[str, list[str]] = {}
    for name, parent, *_ in RIG:
        kids.setdefault(parent, []).append(name)
    lines += [f"    {p} {' '.join(k)}" for p, k in kids.items()]
    return "\n".join(lines + ["  end"]) + "\n"


def motion_values(T: int, seed: int = 0) -> dict[str, np.ndarray]:
    """(T, n) degrees per bone (root: position in file units, then angles): a walk along +z
    at 120 Hz with arms down and small sways elsewhere."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None] / 120.0
    out = {}
    for name, _, _, _, _, dofs in RIG:
        n = len(dofs.split())
        if n:
            phase = rng.uniform(0, 2 * np.pi, (1, n))
            out[name] = 4.0 * np.sin(2 * np.pi * 0.7 * t + phase)
    for side, s in (("l", 1), ("r", -1)):
        out[f"{side}femur"][:, 0] += s * 25 * np.sin(2 * np.pi * t[:, 0])
        out[f"{side}tibia"][:, 0] += 25 + 15 * np.sin(2 * np.pi * t[:, 0])
        out[f"{side}humerus"] += np.array([10, -15 * s, 65 * s])
        out[f"{side}radius"][:, 0] += 30
    root = np.concatenate([0.5 * np.sin(2 * np.pi * t), 16 + 0.3 * np.sin(4 * np.pi * t),
                           21 * t, 3 * np.sin(2 * np.pi * t), 2 * np.sin(np.pi * t),
                           np.zeros_like(t)], axis=1)  # fmt: skip
    return {"root": root, **out}


def amc_file(values, header=(":FULLY-SPECIFIED", ":DEGREES"), first=1, radians=False) -> str:
    T = len(values["root"])
    lines = ["# generated by the mdvae tests", *header]
    for f in range(T):
        lines.append(str(first + f))
        for bone, v in values.items():
            row = v[f].copy()
            if radians:
                row[-3 if bone == "root" else 0 :] = np.radians(row[-3 if bone == "root" else 0 :])
            lines.append(bone + "".join(f" {x:.9g}" for x in row))
    return "\n".join(lines) + "\n"


def write_take_files(folder: Path, T: int = 360, seed: int = 0, name: str = "gen_01", **kw):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "gen.asf").write_text(asf_text())
    path = folder / f"{name}.amc"
    path.write_text(amc_file(motion_values(T, seed), **kw))
    return path, folder / "gen.asf"


@pytest.fixture(scope="module")
def joints():
    return BodyJoints(load_body_model(None))


@pytest.fixture(scope="module")
def generated(tmp_path_factory, joints):
    path, asf = write_take_files(tmp_path_factory.mktemp("amc"))
    take = read_take(path, joints, source=load_source(path, load_asf(asf)))
    return path, asf, take


def _values(path: Path, asf: Path) -> dict[str, np.ndarray]:
    return load_amc(path, asf).layout.values


# --- the dof solve ----------------------------------------------------------------------------


def test_closest_angles_exact_when_reachable_and_closest_when_not():
    rng = np.random.default_rng(0)
    eye = np.eye(3)
    theta = rng.uniform(-1, 1, (50, 3))
    axes = eye[[2, 0, 1]]
    R = chain_rotation(axes, theta)
    np.testing.assert_allclose(closest_angles(R, axes, theta + 0.1), theta, atol=1e-7)
    # one axis: the Frobenius-closest rotation about it, atan2 in closed form
    R = chain_rotation(eye, rng.uniform(-1.5, 1.5, (50, 3)))
    one = closest_angles(R, eye[[0]], np.zeros((50, 1)))[:, 0]
    np.testing.assert_allclose(one, np.arctan2(R[:, 2, 1] - R[:, 1, 2], R[:, 1, 1] + R[:, 2, 2]),
                               atol=1e-9)  # fmt: skip
    # two axes: no grid point leaves a smaller residual turn
    two = closest_angles(R[:5], eye[[2, 0]], np.zeros((5, 2)))
    g = np.linspace(-np.pi, np.pi, 181)
    grid = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)

    def residual(angles, target):
        A = chain_rotation(eye[[2, 0]], angles)
        c = (np.trace(np.swapaxes(A, -1, -2) @ target, axis1=-2, axis2=-1) - 1) / 2
        return np.arccos(np.clip(c, -1, 1))

    for t in range(5):
        best = residual(grid, R[t]).min()
        assert residual(two[t : t + 1], R[t])[0] <= best + 1e-9


def test_format_value():
    assert format_value(9.3721600001, 6) == "9.37216"
    assert format_value(-0.0000001, 6) == "0"
    assert format_value(12.0, 6) == "12"


# --- the way back -----------------------------------------------------------------------------


def test_way_back_without_change_gives_the_file_back(generated, joints):
    path, _, take = generated
    values = write_back_amc(take.source, take.retarget, take.motion, take.motion, joints)
    for bone, v in take.source.layout.values.items():
        np.testing.assert_allclose(v, values[bone], atol=1e-9, err_msg=bone)
    assert amc_text(take.source.layout, values) == path.read_text()  # byte for byte


def _turned(motion: Motion, joint: int, axis: int, degrees: float) -> Motion:
    """``motion`` with SMPL joint ``joint``'s local rotation turned about its own axis."""
    import torch

    from mdvae_cli.geometry.rotations import rotmat_to_rotvec, rotvec_to_rotmat

    pose = np.array(motion.pose_body, dtype=np.float64).reshape(motion.num_frames, -1, 3)
    R = rotvec_to_rotmat(torch.from_numpy(pose[:, joint - 1]))
    turn = np.zeros(3)
    turn[axis] = math.radians(degrees)
    R = R @ rotvec_to_rotmat(torch.from_numpy(turn))
    pose[:, joint - 1] = rotmat_to_rotvec(R).numpy()
    return motion.with_body(pose_body=pose.reshape(np.shape(motion.pose_body)))


def test_dof_limited_bones_take_the_turn_their_dofs_allow(generated, joints):
    _, _, take = generated
    src, layout = take.source, take.source.layout
    # the left knee bends 10 degrees more (SMPL: about its x axis): only ltibia's rx can do it
    bent = _turned(take.motion, 4, 0, 10.0)
    values = write_back_amc(src, take.retarget, take.motion, bent, joints)
    change = {b: np.abs(values[b] - v).max() for b, v in layout.values.items()}
    assert 8.0 < change["ltibia"] < 12.0, change["ltibia"]
    assert all(change[b] < 1e-9 for b in ("rtibia", "lfemur", "lhumerus", "head", "lfingers"))
    assert change["lfoot"] < 2.0  # the ankle keeps its world turn: at most the knee's residue
    # the left elbow bends 10 degrees more (SMPL: about its y axis). lwrist (dof ry, a twist)
    # is the bone the elbow drives; lradius (dof rx) above it bends and takes the turn
    bent = _turned(take.motion, 18, 1, 10.0)
    values = write_back_amc(src, take.retarget, take.motion, bent, joints)
    d_radius = np.abs(values["lradius"] - layout.values["lradius"]).max()
    d_wrist = np.abs(values["lwrist"] - layout.values["lwrist"]).max()
    assert d_radius > 6.0 and d_wrist < 0.5 * d_radius, (d_radius, d_wrist)
    L0 = amc_pose(src, layout, layout.values)[0]
    L1 = amc_pose(src, layout, values)[0]
    for bone in ("rradius", "rwrist", "lhumerus", "lfingers", "lthumb"):  # untouched
        np.testing.assert_allclose(L1[:, src.index(bone)], L0[:, src.index(bone)], atol=1e-9)


# --- the command ------------------------------------------------------------------------------


def _run(*args):
    return CliRunner().invoke(cli, ["denoise", *map(str, args)])


def test_denoise_amc_keeps_header_frames_bones_and_uncovered_values(tmp_path, joints):
    path, asf = write_take_files(tmp_path / "in", first=101,
                                 header=("# a note", ":FULLY-SPECIFIED", ":DEGREES"))  # fmt: skip
    out = tmp_path / "out" / "clean.amc"
    r = _run(path, "-o", out)
    assert r.exit_code == 0, r.output
    before, after = path.read_text().splitlines(), out.read_text().splitlines()
    assert len(after) == len(before)
    assert after[:4] == before[:4]  # comment lines and the header verbatim
    words_before = [ln.split()[0] for ln in before[4:]]
    assert [ln.split()[0] for ln in after[4:]] == words_before  # frame numbers, bone order
    assert after[4] == "101" and after[-len(motion_values(1)) - 1] == "460"
    for line_b, line_a in zip(before, after, strict=True):  # uncovered bones: same text
        if line_b.split()[0] in ("lfingers", "rfingers", "lthumb", "rthumb"):
            assert line_a == line_b
    assert (tmp_path / "out" / "gen.asf").read_text() == asf.read_text()  # the skeleton copied
    v0, v1 = _values(path, asf), _values(out, tmp_path / "out" / "gen.asf")
    assert set(v1) == set(v0) and all(v1[b].shape == v0[b].shape for b in v0)
    take = read_take(path, joints, skeleton=asf)
    src = take.source
    L0, _, _, P0 = amc_pose(src, src.layout, v0)
    L1, _, _, P1 = amc_pose(src, src.layout, v1)
    moved = np.linalg.norm(P1 - P0, axis=-1).mean() * src.layout.metres_per_unit * 1000
    R = np.swapaxes(L0, -1, -2) @ L1
    deg = np.degrees(np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))
    # the denoiser's own change to this sine-wave walk, carried to the skeleton
    assert np.median(deg) < 1.5 and moved < 15.0, (np.median(deg), moved)
    assert np.abs(v1["root"][:, 2] - v0["root"][:, 2]).max() < 0.05 / 0.0564  # z within 5 cm


def _noisy(values, rng, sigma=0.05):
    out = {}
    for bone, v in values.items():
        v = v.copy()
        cols = slice(3, 6) if bone == "root" else slice(None)
        v[:, cols] += np.degrees(rng.normal(0, sigma, v[:, cols].shape))
        out[bone] = v
    return out


def _body_mm(a: Motion, b: Motion, joints) -> float:
    return float(np.linalg.norm(smpl_globals(a, joints)[1] - smpl_globals(b, joints)[1], axis=-1)
                 .mean() * 1000)  # fmt: skip


def test_noisy_amc_comes_back_closer_than_the_npz_path(tmp_path, generated, joints):
    _, asf, take = generated
    noisy = tmp_path / "gen_02.amc"
    noisy.write_text(amc_file(_noisy(motion_values(360), np.random.default_rng(1))))
    shutil.copy(asf, tmp_path / "gen.asf")
    # the write-back, not the foot lock: on this generated take (feet sliding by design) the
    # lock's leg turns cost more through its bones' dofs (29.5 mm against 23.6 by npz)
    assert _run(noisy, "-o", tmp_path / "out.amc", "--feet", "off").exit_code == 0
    assert _run(noisy, "-o", tmp_path / "out.npz", "--feet", "off").exit_code == 0
    betas = take.retarget.betas
    back = read_take(tmp_path / "out.amc", joints, asf, betas=betas).motion
    noisy_motion = read_take(noisy, joints, asf, betas=betas).motion
    from mdvae_cli.formats.npz_io import load_motion

    npz = load_motion(tmp_path / "out.npz")
    err = {name: _body_mm(m, take.motion, joints)
           for name, m in (("noisy", noisy_motion), ("npz", npz), ("amc", back))}  # fmt: skip
    assert err["amc"] < 0.6 * err["noisy"] and err["amc"] <= 1.05 * err["npz"], err


def test_bones_in_any_order_gaps_and_a_cut_off_frame_are_written_as_they_were(tmp_path):
    path, asf = write_take_files(tmp_path, T=200)
    lines = path.read_text().splitlines()
    n = len(motion_values(1)) + 1  # lines per frame
    frame = lines[3 + 5 * n : 3 + 6 * n]  # frame 6: its bones listed backwards
    lines[3 + 5 * n : 3 + 6 * n] = [frame[0], *frame[:0:-1]]
    del lines[3 + 9 * n + 4]  # frame 10 leaves out one bone (it holds frame 9's values)
    text = "\n".join(lines + ["201", lines[4]]) + "\n"  # a last frame cut off after the root
    path.write_text(text)
    out = tmp_path / "out" / "gen_01.amc"
    r = _run(path, "-o", out)
    assert r.exit_code == 0, r.output
    after = out.read_text().splitlines()
    assert [ln.split()[0] for ln in after] == [ln.split()[0] for ln in text.splitlines()]
    assert after[-2:] == ["201", lines[4]]  # the cut-off frame as it was
    changed = [a for a, b in zip(after, text.splitlines(), strict=True) if a != b]
    assert len(changed) > 100 and all(c.split()[0] not in ("lfingers", "rthumb") for c in changed)
    layout = load_amc(path, asf).layout
    assert amc_text(layout, layout.values) == text  # the writer alone: byte for byte


def test_radians_file_gives_the_degrees_result(tmp_path):
    values = motion_values(360)
    for sub, kw in (("deg", {}), ("rad", {"radians": True, "header": (":RADIANS",)})):
        (tmp_path / sub).mkdir()
        (tmp_path / sub / "gen.asf").write_text(asf_text("rad" if sub == "rad" else "deg"))
        (tmp_path / sub / "gen_01.amc").write_text(amc_file(values, **kw))
        r = _run(tmp_path / sub / "gen_01.amc", "-o", tmp_path / sub / "out.amc.gz")
        assert r.exit_code == 0, r.output
    with gzip.open(tmp_path / "rad" / "out.amc.gz", "rt") as fh:
        assert fh.read().splitlines()[1] == ":RADIANS"
    deg = _values(tmp_path / "deg" / "out.amc.gz", tmp_path / "deg" / "gen.asf")
    rad = _values(tmp_path / "rad" / "out.amc.gz", tmp_path / "rad" / "gen.asf")
    for bone, v in deg.items():
        r = rad[bone].copy()
        cols = slice(3, 6) if bone == "root" else slice(None)
        r[:, cols] = np.degrees(r[:, cols])
        np.testing.assert_allclose(r, v, atol=2e-3, err_msg=bone)


def test_folder_of_mixed_takes_each_in_its_own_form(tmp_path, make_motion_file):
    from tests.test_bvh_out import write_rig

    folder = tmp_path / "in"
    write_take_files(folder / "amc", T=160)
    write_rig(folder / "take.bvh", T=40)
    make_motion_file(folder / "walk.npz", T=40)
    r = CliRunner().invoke(cli, ["denoise", str(folder), "-o", str(tmp_path / "out"), "--json"])
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)
    assert data["succeeded"] == 3
    for name in ("amc/gen_01.amc", "amc/gen.asf", "take.bvh", "walk.npz"):
        assert (tmp_path / "out" / name).is_file(), name
    one = tmp_path / "one.npz"  # an AMC take as the cleaned SMPL motion
    assert _run(folder / "amc" / "gen_01.amc", "-o", one).exit_code == 0
    from mdvae_cli.formats.npz_io import load_motion

    assert load_motion(one).num_frames == 160


def test_every_denoise_option_on_an_amc_take(tmp_path):
    path, asf = write_take_files(tmp_path / "in", T=160)
    elsewhere = tmp_path / "skel" / "other.asf"
    elsewhere.parent.mkdir()
    shutil.move(asf, elsewhere)
    out = tmp_path / "out.amc"
    r = CliRunner().invoke(cli, ["denoise", str(path), "-o", str(out), "--asf", str(elsewhere),
                                 "--refine", "2", "--mirror", "--outliers", "--optimize", "1",
                                 "--view", str(tmp_path / "pages"), "--json"])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["files"][0]["result"]["frames"] == 160
    assert (tmp_path / "pages" / "gen_01.html").stat().st_size > 1000
    # the skeleton given with --asf goes next to the output (it reads on its own)
    assert not (tmp_path / "gen.asf").exists()
    assert (tmp_path / "other.asf").read_bytes() == elsewhere.read_bytes()
    assert len(out.read_text().splitlines()) == len(path.read_text().splitlines())


def test_bad_amc_cases_are_one_line_errors(tmp_path):
    path, asf = write_take_files(tmp_path, T=160)
    asf.unlink()
    r = _run(path, "-o", tmp_path / "x.amc")
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 1 and len(lines) == 1 and "--asf" in lines[0] and str(path) in lines[0]
    asf.write_text(asf_text())
    for target, word in (("x.bvh", "not a BVH take"), ("x.amc.npz.gz", ".npz")):
        r = _run(path, "-o", tmp_path / target)
        assert r.exit_code == 1 and word in r.output, r.output
    r = _run(REPO / "examples" / "walk.npz", "-o", tmp_path / "w.amc")
    assert r.exit_code == 1 and "not an AMC take" in r.output
    wrong = tmp_path / "wrong.asf"  # a skeleton that lacks the file's bones
    wrong.write_text(asf_text().replace("name lthumb", "name lpinky").replace(" lthumb", " lpinky"))
    r = _run(path, "-o", tmp_path / "x.amc", "--asf", wrong)
    assert r.exit_code == 1 and "lthumb" in r.output and not (tmp_path / "x.amc").exists()
    body = BodyJoints(load_body_model(None))
    take = read_take(path, body, asf)
    with pytest.raises(InputError, match="written back as .amc"):
        write_take(take, take.motion, tmp_path / "x.bvh", body)


# --- CMU --------------------------------------------------------------------------------------


@needs_cmu
def test_cmu_take_way_back_is_exact_and_denoises(tmp_path, joints):
    folder = tmp_path / "07"
    folder.mkdir()
    shutil.copy(CMU / "asfamc/07/07.asf", folder / "07.asf")
    with gzip.open(CMU / "asfamc/07/07_01.amc.gz", "rb") as fh:
        raw = fh.read()
    path = folder / "07_01.amc"
    path.write_bytes(raw)
    take = read_take(path, joints, folder / "07.asf")
    same = write_back_amc(take.source, take.retarget, take.motion, take.motion, joints)
    assert amc_text(take.source.layout, same).encode() == raw  # CRLF and all
    r = _run(path, "-o", tmp_path / "out" / "07_01.amc.gz")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "out" / "07.asf").is_file()
    with gzip.open(tmp_path / "out" / "07_01.amc.gz", "rb") as fh:
        out = fh.read()
    assert out.count(b"\r\n") == raw.count(b"\r\n")
    a, b = raw.decode().splitlines(), out.decode().splitlines()
    assert a[:3] == b[:3] and len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        if x.split()[0] in ("lfingers", "rthumb", "lhipjoint"):
            assert x == y


def test_add_noise_and_eval_read_an_amc_take_with_its_skeleton_elsewhere(tmp_path):
    path, asf = write_take_files(tmp_path / "in", T=90)
    lone = tmp_path / "lone" / path.name
    lone.parent.mkdir()
    lone.write_bytes(path.read_bytes())  # no .asf beside it
    out = tmp_path / "noisy.amc"
    r = CliRunner().invoke(cli, ["add-noise", str(lone), "-o", str(out)])
    assert r.exit_code == 1 and "--asf" in r.output and not out.exists()
    noisy = ["add-noise", "--sigma", "0.1", str(lone), "-o", str(out), "--asf", str(asf)]
    r = CliRunner().invoke(cli, noisy)
    assert r.exit_code == 0, r.output
    before, after = _values(path, asf), _values(out, asf)
    assert sorted(after) == sorted(before)  # an AMC of the same bones, noisy
    assert max(np.abs(after[b] - before[b]).max() for b in before) > 1.0  # degrees
    r = CliRunner().invoke(cli, ["eval", "--gt", str(lone), "--pred", str(out), "--asf",
                                 str(asf), "--json"])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["files"][0]["result"]["v2v_cm"] > 1.0

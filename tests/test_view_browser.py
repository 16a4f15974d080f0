"""``mdvae view``'s page in a real browser (headless Chromium, Debian's ``chromium`` package):
it starts, plays, draws different frames as the timeline moves, rebuilds the posed joints,
fetches nothing and logs no error. Skipped where Chromium is not installed."""

from __future__ import annotations

import contextlib
import json
import time

import numpy as np
import pytest

from benchmarks.chromium import Chromium, file_url, find_chromium
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.formats.npz_io import motion_from_arrays
from mdvae_cli.view.page import build_view_page, write_view_page
from mdvae_cli.view.pose import pose_skeleton
from tests.conftest import motion_arrays

pytestmark = pytest.mark.skipif(
    find_chromium() is None,
    reason="chromium not installed (apt-get install chromium): the page is not run in a browser",
)

READY = "window.mdvaeView && (window.mdvaeView.ready || window.mdvaeView.errors.length > 0)"
#: the fraction of the scene canvas's bytes that differ between two frames
SCENE_CHANGE = """(async () => {
  const c = document.getElementById('scene'), ctx = c.getContext('2d');
  const grab = () => ctx.getImageData(0, 0, c.width, c.height).data;
  window.mdvaeView.seek(%d); const a = grab();
  window.mdvaeView.seek(%d); const b = grab();
  let n = 0; for (let i = 0; i < a.length; i++) if (a[i] !== b[i]) n++;
  return n / a.length;
})()"""


@contextlib.contextmanager
def in_browser(path):
    """A page file opened in a fresh headless browser, ready: -> its tab."""
    browser = Chromium.launch()
    try:
        tab = browser.open_page(width=1000, height=800)
        tab.navigate(file_url(path))
        tab.wait_for(READY, timeout=60)
        yield tab
    finally:
        browser.close()


@pytest.fixture(scope="module")
def page(tmp_path_factory, tiny_body):
    """One page in one browser for the module: a noisy 30 Hz take and a clean 60 Hz take of
    another length (the page aligns them by time)."""
    rng = np.random.default_rng(0)
    noisy = motion_from_arrays(motion_arrays(T=60, fps=30.0, seed=0))
    noisy = noisy.with_body(pose_body=noisy.pose_body + rng.normal(0, 0.15, (60, 21, 3)))
    clean = motion_from_arrays(motion_arrays(T=150, fps=60.0, seed=0))
    body = BodyModel(tiny_body)
    path = tmp_path_factory.mktemp("view") / "page.html"
    write_view_page(build_view_page([("noisy", noisy), ("clean", clean)], body), path)
    browser = Chromium.launch()
    try:
        tab = browser.open_page(width=1000, height=800)
        tab.navigate(file_url(path))
        tab.wait_for(READY, timeout=60)
        yield tab, path, [pose_skeleton(m, body).joints for m in (noisy, clean)]
    finally:
        browser.close()


def test_page_starts_without_errors_or_requests(page):
    tab, path, _ = page
    assert tab.evaluate("window.mdvaeView.errors") == []
    assert tab.errors() == []
    assert tab.requests() == [file_url(path)]  # the file itself, nothing else
    state = tab.evaluate("window.mdvaeView.state()")
    assert state["mesh"] and state["frames"] == 150 and state["fps"] == 60
    assert tab.evaluate("window.mdvaeView.firstFrameMs") > 0


def test_timeline_moves_the_picture_and_keeps_motions_aligned_by_time(page):
    tab, _, _ = page
    assert tab.evaluate(SCENE_CHANGE % (0, 80)) > 0.002  # the bodies moved
    assert tab.evaluate(SCENE_CHANGE % (80, 80)) == 0.0  # drawing is deterministic
    shots = []
    for frame in (0, 80):
        state = tab.evaluate(f"window.mdvaeView.seek({frame})")
        shots.append(tab.screenshot())
    assert shots[0] != shots[1]
    # timeline frame 80 at 60 Hz = 1.333 s: frame 40 of the 30 Hz take, 80 of the 60 Hz one
    assert [m["frame"] for m in state["motions"]] == [40, 80]
    # past the end of the shorter take, it holds its last frame
    state = tab.evaluate("window.mdvaeView.seek(149)")
    assert [m["frame"] for m in state["motions"]] == [59, 149]


def test_page_rebuilds_the_posed_joints(page):
    tab, _, truth = page
    for i, frames in ((0, (0, 33, 59)), (1, (0, 77, 149))):
        for f in frames:
            got = np.array(tab.evaluate(f"window.mdvaeView.jointsAt({i}, {f})")).reshape(22, 3)
            # the noisy take's rotations are stored in coarser steps (under its own noise)
            assert np.abs(got - truth[i][f]).max() < (8e-3 if i == 0 else 2e-3)


def test_controls_change_the_picture_without_errors(page):
    tab, _, _ = page
    tab.evaluate("window.mdvaeView.seek(50)")
    before = tab.screenshot()
    for call in ("setLayout('overlay')", "setBody('skeleton')", "setBody('mesh')",
                 "setPlot('bend', 4)", "setPlot('height', 10, 1)", "setPlot('speed', 20)",
                 "setPlot('rotation', 0, 0)", "setLayout('side')", "setBody('both')"):  # fmt: skip
        tab.evaluate(f"window.mdvaeView.{call}")
        assert tab.evaluate("window.mdvaeView.errors") == [], call
    tab.evaluate("window.mdvaeView.setLayout('overlay')")
    assert tab.screenshot() != before
    tab.evaluate("window.mdvaeView.setLayout('side')")
    assert tab.errors() == []


def test_play_advances_time(page):
    tab, _, _ = page
    tab.evaluate("window.mdvaeView.seek(0); window.mdvaeView.play()")
    start = time.monotonic()
    while tab.evaluate("window.mdvaeView.state().time") == 0 and time.monotonic() - start < 5:
        time.sleep(0.05)
    state = tab.evaluate("window.mdvaeView.state()")
    tab.evaluate("window.mdvaeView.pause()")
    assert state["playing"] and state["time"] > 0
    assert json.dumps(tab.errors()) == "[]"


#: the plot canvas's pixel (r, g, b) at CSS position (x, y)
PLOT_PIXEL = """(() => {
  const c = document.getElementById('plot'), d = window.devicePixelRatio || 1;
  const px = c.getContext('2d').getImageData(Math.round(%f * d), Math.round(%f * d), 1, 1);
  return Array.from(px.data.slice(0, 3));
})()"""


def test_filled_frames_are_marked_on_the_plot(tmp_path, tiny_body):
    """A take with frames 20-29 missing in the file: the page says which frames are filled,
    draws a bar in the motion's colour over them and none elsewhere, and says so in the
    legend."""
    motion = motion_from_arrays(motion_arrays(T=60, fps=30.0, seed=1))
    motion.joint_mask = np.ones((60, 22), bool)
    motion.joint_mask[20:30, 16] = False
    page_ = build_view_page([("holes", motion)], BodyModel(tiny_body), mesh=False)
    assert page_.motions[0]["filled_frames"] == 10
    path = tmp_path / "holes.html"
    write_view_page(page_, path)
    with in_browser(path) as tab:
        assert tab.evaluate("window.mdvaeView.seek(25)")["motions"][0]["filled"] is True
        assert tab.evaluate("window.mdvaeView.seek(40)")["motions"][0]["filled"] is False
        width = tab.evaluate("document.getElementById('plot').clientWidth")
        x = lambda f: 58 + f / 59 * (width - 70)  # noqa: E731  (plotLayout: left 58, right 12)
        inside = tab.evaluate(PLOT_PIXEL % (x(25), 11.5))
        outside = tab.evaluate(PLOT_PIXEL % (x(45), 11.5))
        assert inside == [0xD9, 0x48, 0x0F]  # PALETTE[0]
        assert outside != inside
        assert "10 filled" in tab.evaluate("document.getElementById('legend').textContent")
        assert tab.evaluate("window.mdvaeView.errors") == [] and tab.errors() == []


#: per panel of n equal columns of the scene canvas, the pixels of colour rgb below the labels
PANEL_PIXELS = """(() => {
  const c = document.getElementById('scene'), d = window.devicePixelRatio || 1;
  const px = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  const n = %d, rgb = %s, out = new Array(n).fill(0);
  for (let y = Math.round(60 * d); y < c.height; y++) for (let x = 0; x < c.width; x++) {
    const i = 4 * (y * c.width + x);
    const hit = px[i] === rgb[0] && px[i + 1] === rgb[1] && px[i + 2] === rgb[2];
    if (hit) out[Math.floor((x * n) / c.width)]++;
  }
  return out;
})()"""


def test_side_by_side_panels_each_show_their_own_motion_wherever_it_is(tmp_path, tiny_body):
    """Two takes 11.7 m apart (a video estimate in camera space beside a studio take): side by
    side, each panel looks at its own motion (before: both at the point between them, where
    neither is); overlaid, one camera sees them both from the middle. Many motions: the plot
    grows to keep its curves above the contact strips."""
    near = motion_from_arrays(motion_arrays(T=40, fps=30.0, seed=0))
    far = motion_from_arrays(motion_arrays(T=40, fps=30.0, seed=0))
    far = far.with_body(trans=far.trans + np.array([10.0, 6.0, 0.0]))
    page_ = build_view_page([("near", near), ("far", far)], BodyModel(tiny_body), mesh=False)
    path = tmp_path / "apart.html"
    write_view_page(page_, path)
    many = [(f"m{i}", near) for i in range(12)]
    write_view_page(build_view_page(many, BodyModel(tiny_body), mesh=False), tmp_path / "many.html")
    browser = Chromium.launch()
    try:
        tab = browser.open_page(width=1000, height=800)
        tab.navigate(file_url(path))
        tab.wait_for(READY, timeout=60)
        tab.evaluate("window.mdvaeView.seek(20)")
        near_px = tab.evaluate(PANEL_PIXELS % (2, "[0xd9, 0x48, 0x0f]"))  # PALETTE[0]
        far_px = tab.evaluate(PANEL_PIXELS % (2, "[0x1c, 0x7e, 0xd6]"))  # PALETTE[1]
        assert near_px[0] > 300 and far_px[1] > 300, (near_px, far_px)
        assert near_px[1] == 0 and far_px[0] == 0
        # the camera stays on each motion when it stops following
        tab.evaluate("document.getElementById('follow').click(); window.mdvaeView.seek(39)")
        assert tab.evaluate(PANEL_PIXELS % (2, "[0x1c, 0x7e, 0xd6]"))[1] > 300
        assert tab.evaluate("window.mdvaeView.errors") == [] and tab.errors() == []
        tab.navigate(file_url(tmp_path / "many.html"))
        tab.wait_for(READY, timeout=60)
        height = tab.evaluate("document.getElementById('plot').clientHeight")
        assert height == 190 + 18 * 12 - 2  # less its border; it was 228 whatever the count
        # the test hook's plot choice shows in the page's own menus (they kept the old one)
        tab.evaluate("window.mdvaeView.setPlot('height', 7, 0)")
        menus = "['series', 'joint'].map((id) => document.getElementById(id).value)"
        assert tab.evaluate(menus) == ["height", "7"]
    finally:
        browser.close()


def test_motions_on_other_floors_and_far_apart_are_framed_whole(tmp_path, tiny_body):
    """A video estimate in camera space beside a studio take: its floor a metre lower and
    8 m away. Side by side, each panel aims at its own motion's floor (the camera aimed 0.9 m
    over the lowest floor of all, cutting the other off); overlaid, the camera backs off until
    both are in view (one was 8 m off screen); twelve motions get twelve colours."""
    near = motion_from_arrays(motion_arrays(T=40, fps=30.0, seed=0))
    far = near.with_body(trans=near.trans + np.array([0.0, 8.0, -1.0]))
    path = tmp_path / "floors.html"
    page_ = build_view_page([("near", near), ("far", far)], BodyModel(tiny_body), mesh=False)
    write_view_page(page_, path)
    with in_browser(path) as tab:
        tab.evaluate("window.mdvaeView.seek(20)")
        panels = tab.evaluate("window.mdvaeView.panels")
        aims = [p["target"][2] for p in panels]
        assert len(panels) == 2 and abs((aims[0] - aims[1]) - 1.0) < 0.05, panels
        assert all(p["distance"] == panels[0]["distance"] for p in panels)  # no backing off
        tab.evaluate("(() => { const el = document.getElementById('layout'); "
                     "el.value = 'overlay'; el.dispatchEvent(new Event('change')); "
                     "window.mdvaeView.seek(21); })()")  # fmt: skip
        (panel,) = tab.evaluate("window.mdvaeView.panels")
        assert panel["distance"] > 2 * panels[0]["distance"], panel
        near_px = tab.evaluate(PANEL_PIXELS % (1, "[0xd9, 0x48, 0x0f]"))[0]  # PALETTE[0]
        far_px = tab.evaluate(PANEL_PIXELS % (1, "[0x1c, 0x7e, 0xd6]"))[0]  # PALETTE[1]
        assert near_px > 100 and far_px > 100, (near_px, far_px)
        assert tab.evaluate("window.mdvaeView.errors") == [] and tab.errors() == []
    from mdvae_cli.view.page import PALETTE

    assert len(set(PALETTE)) == len(PALETTE) == 12
